"""Bad input to the footskate package (torch-only, so it has its own error type)."""


class FootskateError(ValueError):
    """A file, argument or array is unusable; the message names it."""
