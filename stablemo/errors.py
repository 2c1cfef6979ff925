"""The one error type users see for bad input: it names the file or argument at fault."""


class StableMoError(Exception):
    """Bad input (file, argument, configuration). The CLI prints it as one line and exits 2."""
