"""The errors a unit raises when its input cannot make a clip, or its output cannot be written, and
the one a command raises when it cannot start."""


class InputError(Exception):
    """Bad or missing input for one unit; the message names the file or record and the cause."""


class OutputError(Exception):
    """A file of one clip or unit cannot be written; the message names the path and the cause."""


class CannotStart(Exception):
    """A run cannot start (a bad option or setting, a missing input, an unwritable output); the
    message is one line, printed as ``cannot start: <message>`` with exit status 2."""


def root_cause(error: BaseException) -> BaseException:
    """The innermost exception of a chain (Beam re-raises a step's error as a RuntimeError; numba
    hands back a Ctrl-C taken during a kernel's call as a SystemError caused by it)."""
    while (inner := error.__cause__ or error.__context__) is not None:
        error = inner
    return error


def interruption(error: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C behind ``error``, if any exception of its chain (causes and contexts) is one: a
    Ctrl-C taken while another error was being handled (a retry's wait) has that error as its
    context, and Beam or numba may wrap it in turn."""
    seen: list[BaseException] = []
    link: BaseException | None = error
    while link is not None and not any(link is other for other in seen):
        if isinstance(link, KeyboardInterrupt):
            return link
        seen.append(link)
        link = link.__cause__ or link.__context__
    return None
