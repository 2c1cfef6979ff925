"""The one error type users see for bad input: it names the file or argument at fault."""


class StableMoError(Exception):
    """Bad input (file, argument, configuration). The CLI prints it as one line and exits 2."""


def run_script(main, name: str, argv=None) -> int:
    """Exit code of `main(argv)` for a script's `__main__`: a StableMoError becomes one line on
    stderr and exit code 2, as in the CLI."""
    import sys

    try:
        rc = main(argv)
    except StableMoError as err:
        print(f"{name}: error: {err}", file=sys.stderr)
        return 2
    return rc if isinstance(rc, int) else 0
