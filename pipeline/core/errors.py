"""The error a unit raises when its input cannot make a clip."""


class InputError(Exception):
    """Bad or missing input for one unit; the message names the file or record and the cause."""
