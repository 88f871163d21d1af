"""The errors a unit raises when its input cannot make a clip, or its output cannot be written."""


class InputError(Exception):
    """Bad or missing input for one unit; the message names the file or record and the cause."""


class OutputError(Exception):
    """A file of one clip or unit cannot be written; the message names the path and the cause."""


def root_cause(error: BaseException) -> BaseException:
    """The innermost exception of a chain (Beam re-raises a step's error as a RuntimeError; numba
    hands back a Ctrl-C taken during a kernel's call as a SystemError caused by it)."""
    while (error.__cause__ or error.__context__) is not None:
        error = error.__cause__ or error.__context__
    return error
