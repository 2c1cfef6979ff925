"""The one error type users see for bad input: it names the file or argument at fault."""

import re


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


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def one_line(message: str) -> str:
    """An error message as one line (the CLI prints errors as one line, naming the file).

    torch's weights_only refusal spans many lines with terminal escapes and advises re-loading with
    weights_only=False, which is exactly what must not be done with a file that needs it: only its
    reason is kept.
    """
    text = _ANSI.sub("", message)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if len(lines) <= 1:
        return lines[0] if lines else text
    reason = next((line.split("WeightsUnpickler error:", 1)[1].strip() for line in lines
                   if "WeightsUnpickler error:" in line), None)
    if reason is None:
        return " ".join(lines)
    head = lines[0]
    cut = head.find(" (UnpicklingError")
    head = head[:cut] if cut > 0 else head
    reason = reason.split(" was not an allowed global")[0].split(". ")[0].rstrip(".")
    return f"{head} (it holds pickled objects that safe loading (weights_only) refuses: {reason})"
