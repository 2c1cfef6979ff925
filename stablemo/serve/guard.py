"""What the server refuses before any route runs, and the JSON reader every route uses.

`Guard` is a pure ASGI middleware, so every route gets the same checks in the same order:

1. Host must be one of this server's own names with the port it listens on (127.0.0.1, localhost,
   [::1], plus the --host it was started with): a web page cannot reach the server through a
   DNS name of its own that resolves to 127.0.0.1 (DNS rebinding) and read the answers. 400.
2. An Origin header must be this server's own (http://<Host>): any other web page the user visits
   is refused, even for the "simple" requests a browser sends without asking first. 403.
3. A POST must be `Content-Type: application/json`: the content types a page may send without a
   CORS preflight (text/plain, forms) are refused. 415.
4. The body is read here, chunk by chunk, never past `max_body` bytes (413 as soon as it is over,
   at once when Content-Length says so) and within `body_timeout` seconds (408: a client trickling
   its body cannot hold a request open).

`read_json` parses a body and refuses, naming the field (`control.targets[3][0]: ...`), nesting
deeper than MAX_JSON_DEPTH, integers longer than MAX_INT_DIGITS digits, numbers that overflow a
float, NaN/Infinity and strings with lone surrogates: each of these was an HTTP 500 (RecursionError,
int->float OverflowError, UnicodeEncodeError while writing the answer) instead of a 400.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
from typing import Any

from stablemo.errors import StableMoError, one_line

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")
# The largest honest body is a joint-control request with a target at every (frame, joint) of the
# longest motion: 196 frames x 22 joints of [frame, joint, x, y, z] at full float64 precision is
# 0.31 MB (tests/test_serve_hostile.py measures it); a 300 s timeline of 1 s lines of 1000
# characters is ~0.3 MB. 1 MiB leaves a margin of over 3x.
MAX_BODY_BYTES = 1 << 20
BODY_TIMEOUT_S = 10.0  # the whole body must arrive within this, counted from the first read
MAX_JSON_DEPTH = 8  # the API's deepest value (control.targets[i][k]) is at depth 4
MAX_INT_DIGITS = 20  # seeds go up to 2**63 - 1 (19 digits); nothing else needs more
JSON_THREAD_BYTES = 64 << 10  # bodies larger than this are parsed off the event loop


def _headers(scope) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, value in scope.get("headers", ()):
        out.setdefault(name.decode("latin-1").lower(), []).append(value.decode("latin-1"))
    return out


def bracket_host(host: str) -> str:
    """The Host-header spelling of a listening address ('::1' -> '[::1]')."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


class Guard:
    """Pure ASGI middleware (see the module docstring). hosts: the names a client may put in Host,
    without port (the port is the one the request came in on); tests add 'testserver' here."""

    def __init__(self, app, hosts=LOOPBACK_HOSTS, max_body: int = MAX_BODY_BYTES,
                 body_timeout: float = BODY_TIMEOUT_S):
        self.app, self.max_body, self.body_timeout = app, max_body, body_timeout
        self.hosts = tuple(dict.fromkeys(bracket_host(h).lower() for h in hosts))

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = _headers(scope)
        problem = self.check_headers(scope, headers)
        if problem is None and (scope["method"] == "POST" or "content-length" in headers
                                or "transfer-encoding" in headers):
            body, problem = await self.read_body(headers, receive)
            if body is None and problem is None:
                return  # the client went away while sending: nobody to answer
            receive = _replay(body, receive) if problem is None else receive
        if problem is not None:
            return await refuse(send, *problem)
        await self.app(scope, receive, send)

    def allowed_hosts(self, scope) -> set[str]:
        port = (scope.get("server") or (None, None))[1]
        names = {f"{h}:{port}" for h in self.hosts} if port else set()
        if port in (80, None):  # the default port may be left out of Host
            names.update(self.hosts)
        return names

    def check_headers(self, scope, headers: dict[str, list[str]]) -> tuple[int, str] | None:
        """(status, message) of the first header that is refused, or None."""
        hosts = headers.get("host", [])
        if len(hosts) != 1:
            return 400, f"Host: expected one Host header, got {len(hosts)}"
        host = hosts[0].strip().lower()
        allowed = self.allowed_hosts(scope)
        if host not in allowed:
            return 400, (f"Host: {hosts[0][:80]!r} is not this server (it answers to {', '.join(sorted(allowed))}; "
                         "stablemo serve --host NAME adds a name)")
        origins = headers.get("origin", [])
        if origins and (len(origins) != 1 or origins[0].strip().lower() != f"http://{host}"):
            return 403, (f"Origin: {origins[0][:80]!r} is not this server's page (http://{host}); "
                         "requests from other web pages are refused")
        if scope["method"] == "POST":
            ctype = headers.get("content-type", [""])[0]
            if ctype.split(";", 1)[0].strip().lower() != "application/json":
                return 415, f"Content-Type: expected application/json, got {ctype[:80]!r}"
        return None

    async def read_body(self, headers, receive) -> tuple[bytes | None, tuple[int, str] | None]:
        """(the whole body, None), (None, (status, message)) when it is refused, or (None, None)
        when the client disconnected. Never holds more than max_body bytes."""
        over = (413, f"request: the body is over {self.max_body} bytes ({self.max_body / 2**20:g} MiB), "
                     "the most a request may send")
        lengths = headers.get("content-length", [])
        if lengths:
            length = lengths[0].strip()
            if len(set(lengths)) != 1 or not (length.isascii() and length.isdigit()):
                return None, (400, f"Content-Length: expected one whole number, got {', '.join(lengths)[:80]!r}")
            if len(length) > 18 or int(length) > self.max_body:
                return None, over
        chunks, size = [], 0
        deadline = asyncio.get_running_loop().time() + self.body_timeout
        while True:
            left = deadline - asyncio.get_running_loop().time()
            try:
                message = await asyncio.wait_for(receive(), max(left, 0.0))
            except TimeoutError:
                return None, (408, f"request: the body did not arrive within {self.body_timeout:g} s")
            if message["type"] == "http.disconnect":
                return None, None
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body:
                return None, over
            chunks.append(chunk)
            if not message.get("more_body", False):
                return b"".join(chunks), None


def _replay(body: bytes, receive):
    """A receive() that hands the app the body already read, then the client's own messages
    (a disconnect, which a streaming answer listens for)."""
    sent = False

    async def replay():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


async def refuse(send, status: int, message: str) -> None:
    body = json.dumps({"error": one_line(message)}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


# ---- JSON ---------------------------------------------------------------------------------------

class _Refused:
    """A JSON value the parser saw but will not hand on; the tree walk names where it was."""

    __slots__ = ("reason",)

    def __init__(self, reason: str):
        self.reason = reason


def _parse_int(text: str):
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:  # int() of it would cost quadratic time, and float() of it overflows
        return _Refused(f"an integer of {digits} digits, at most {MAX_INT_DIGITS}")
    return int(text)


def _parse_float(text: str):
    value = float(text)
    return value if math.isfinite(value) else _Refused(f"{text[:40]} is out of a number's range")


def _parse_constant(text: str):
    return _Refused(f"{text} is not a JSON number")


def _path(parts: list) -> str:
    """'control.targets[3][0]'; inside a body that is not an object: 'request[0].text'."""
    out = "request" if parts and isinstance(parts[0], int) else ""
    for part in parts:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "request"


def _has_surrogate(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _check_tree(value: Any) -> None:
    """Walk the parsed body without recursion: depth, refused numbers, lone surrogates (a string
    that cannot be written back as UTF-8, e.g. in an error message naming it)."""
    stack = [(value, [])]
    while stack:
        node, path = stack.pop()
        if len(path) >= MAX_JSON_DEPTH and isinstance(node, (list, dict)):
            raise StableMoError(f"{_path(path)}: nested deeper than {MAX_JSON_DEPTH} levels")
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, item in items:
            if isinstance(key, str) and _has_surrogate(key):
                raise StableMoError(f"{_path(path)}: a field name is not valid Unicode (a lone surrogate)")
            kind = type(item)
            if kind is list or kind is dict:
                stack.append((item, [*path, key]))
            elif kind is _Refused:
                raise StableMoError(f"{_path([*path, key])}: {item.reason}")
            elif kind is str and _has_surrogate(item):
                raise StableMoError(f"{_path([*path, key])}: not valid Unicode (a lone surrogate)")
    if isinstance(value, _Refused):
        raise StableMoError(f"request: {value.reason}")
    if isinstance(value, str) and _has_surrogate(value):
        raise StableMoError("request: not valid Unicode (a lone surrogate)")


_TOKEN = re.compile(r'[\[\]{}",:]')


def _deep_field(text: str) -> str:
    """The path at which `text` first nests deeper than MAX_JSON_DEPTH (only when json.loads gave
    up with RecursionError, so only for hostile bodies)."""
    stack: list[list] = []  # per open container: ["[", index] or ["{", key]
    key, pos = None, 0
    while (m := _TOKEN.search(text, pos)) is not None:
        c, pos = m.group(), m.end()
        if c == '"':
            try:
                key, pos = json.decoder.scanstring(text, pos)
            except (json.JSONDecodeError, ValueError):
                break
        elif c in "[{":
            if len(stack) >= MAX_JSON_DEPTH:
                return _path([part for _, part in stack])
            stack.append(["[", 0] if c == "[" else ["{", None])
        elif not stack:
            break
        elif c in ":,":  # a key ends / the next item of an array begins (anything else is not JSON: ignored)
            if c == ":" and stack[-1][0] == "{":
                stack[-1][1] = key
            elif c == "," and stack[-1][0] == "[":
                stack[-1][1] += 1
        else:  # ] or }
            stack.pop()
    return "request"


def loads(body: bytes) -> Any:
    """A request body -> its JSON value, or a StableMoError naming the field (module docstring)."""
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError as err:
        raise StableMoError(f"request: the body is not valid JSON (not UTF-8: {err.reason} at byte {err.start})") from None
    try:
        value = json.loads(text, parse_int=_parse_int, parse_float=_parse_float, parse_constant=_parse_constant)
    except json.JSONDecodeError as err:
        raise StableMoError(f"request: the body is not valid JSON ({err})") from None
    except RecursionError:
        raise StableMoError(f"{_deep_field(text)}: nested deeper than {MAX_JSON_DEPTH} levels") from None
    _check_tree(value)
    return value


async def read_json(request) -> Any:
    """The request's body as checked JSON; a large body is parsed on a thread so that the event
    loop keeps answering other requests meanwhile (the Guard has capped it at MAX_BODY_BYTES)."""
    body = await request.body()
    if len(body) > JSON_THREAD_BYTES:
        return await asyncio.to_thread(loads, body)
    return loads(body)


__all__ = ["BODY_TIMEOUT_S", "Guard", "LOOPBACK_HOSTS", "MAX_BODY_BYTES", "MAX_INT_DIGITS", "MAX_JSON_DEPTH",
           "bracket_host", "loads", "read_json"]
