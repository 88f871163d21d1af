"""The errors a unit raises when its input cannot make a clip, or its output cannot be written."""


class InputError(Exception):
    """Bad or missing input for one unit; the message names the file or record and the cause."""


class OutputError(Exception):
    """A file of one clip or unit cannot be written; the message names the path and the cause."""
