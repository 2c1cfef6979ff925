"""The one error type users see for bad input: it names the file or argument at fault."""


from footskate.errors import one_line  # noqa: F401  (the one message cleaner, shared with footskate)


class StableMoError(Exception):
    """Bad input (file, argument, configuration). The CLI prints it as one line and exits 2."""


def run_script(main, name: str, argv=None) -> int:
    """Exit code of `main(argv)` for a script's `__main__`: a StableMoError becomes one line on
    stderr and exit code 2, as in the CLI."""
    import sys

    try:
        rc = main(argv)
    except StableMoError as err:
        print(f"{name}: error: {one_line(str(err))}", file=sys.stderr)
        return 2
    return rc if isinstance(rc, int) else 0


def yaml_error_line(path, err) -> str:
    """A YAML parse error as `<path>: line N: <problem>`: PyYAML names the file it parsed from a
    string `"<unicode string>"`, which tells the user nothing."""
    mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
    problem = getattr(err, "problem", None) or getattr(err, "context", None)
    if mark is None or not problem:
        return f"{path}: not valid YAML ({one_line(str(err))})"
    return f"{path}: line {mark.line + 1}, column {mark.column + 1}: not valid YAML ({problem})"
