"""The one error type a user sees: the CLI prints its message and exits 2."""


class Eve3dError(Exception):
    """A problem with the user's input or configuration; the CLI prints it and exits 2."""
