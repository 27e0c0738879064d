"""Error types shared by the library and the CLI."""


class BrlInputError(Exception):
    """Bad input from the user (file, option, data): the CLI prints it on one line and exits with 2."""


class BrlWriteError(Exception):
    """An output could not be written at run time (disk full, permissions): the CLI prints it on one line and exits
    with 1; atomic writes leave the output directory resumable."""
