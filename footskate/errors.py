"""Bad input to the footskate package (torch-only, so it has its own error type), and the one way
both packages turn an error message into the one line a user sees."""

import re


class FootskateError(ValueError):
    """A file, argument or array is unusable; the message names it."""


_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# torch's weights_only refusal starts with this (every torch 2.x wording seen so far)
_WEIGHTS_ONLY_FAILED = "Weights only load failed"
# where torch states what it refused, in the wordings of torch 2.4-2.13: "WeightsUnpickler error:
# Unsupported global: GLOBAL x.Y was not an allowed global ...", "Trying to load unsupported GLOBAL
# posix.system whose module posix is blocked", "WeightsUnpickler error: \n\nUnsupported operand 149"
_REFUSAL_REASONS = ("WeightsUnpickler error:", "Trying to load unsupported", "Unsupported global",
                    "Unsupported operand", "Unsupported class")
# the end of what the refused object is named by, in torch's wordings
_REASON_ENDS = (" was not an allowed global", " whose module", ". Please use", " Check the documentation")
# any sentence giving the advice to load with weights_only=False, however torch words it: never
# repeated to the user, whose file it is exactly what must not be done to
_UNSAFE_ADVICE = re.compile(r"[^.\n]*weights_only`?\s*(?:=|set to|to)\s*`?False[^.\n]*\.?\s*", re.IGNORECASE)


def one_line(message: str) -> str:
    """An error message as one line (the CLI prints errors as one line, naming the file).

    torch's weights_only refusal spans many lines with terminal escapes and advises re-loading with
    weights_only=False, which is exactly what must not be done with a file that needs it: only its
    reason is kept, and any advice to load with weights_only=False is dropped from any message.
    """
    text = _ANSI.sub("", message)
    if _WEIGHTS_ONLY_FAILED in text:
        text = _weights_only_refusal(text)
    text = _UNSAFE_ADVICE.sub("", text)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return " ".join(lines) if lines else text.strip()


def _weights_only_refusal(text: str) -> str:
    """`<what the caller said> (it holds pickled objects that safe loading (weights_only) refuses:
    <the refused global or opcode>)` from a message embedding torch's refusal."""
    head, _, torch_text = text.partition(_WEIGHTS_ONLY_FAILED)
    # the caller's own words end with "(" or "(UnpicklingError: " right before torch's text
    head = re.sub(r"\s*\((?:[A-Za-z_.]*(?:Error|Exception)\s*:\s*)?$", "", head.strip()).rstrip(" :(")
    reason = _refusal_reason(torch_text)
    what = "it holds pickled objects that safe loading (weights_only) refuses"
    what += f": {reason}" if reason else ""
    return f"{head} ({what})" if head else what


def _refusal_reason(torch_text: str) -> str:
    """The refused global or opcode named in torch's refusal text; "" when it names none."""
    flat = " ".join(line.strip() for line in torch_text.splitlines() if line.strip())
    for marker in _REFUSAL_REASONS:
        at = flat.find(marker)
        if at < 0:
            continue
        reason = flat[at:]
        if marker == "WeightsUnpickler error:":
            reason = reason[len(marker):].strip()
        for end in _REASON_ENDS:
            reason = reason.split(end)[0]
        reason = reason.strip().rstrip(".")
        if reason:
            return reason
    return ""
