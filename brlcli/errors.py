"""Error types shared by the library and the CLI."""


class BrlInputError(Exception):
    """Bad input from the user (file, option, data): the CLI prints it on one line and exits with 2."""
