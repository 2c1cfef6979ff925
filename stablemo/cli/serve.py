"""`stablemo serve`: the local page and JSON API (docs/serve.md).

    stablemo serve                                   # demo student (default) + teacher
    stablemo serve --bundle bundles/my_model --port 8000
    stablemo serve --bundle fast=bundles/demo_lcm --bundle slow=bundles/demo --host 0.0.0.0
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.inference.bundle import ASSETS, DEMO_BUNDLE, DEMO_STUDENT
from stablemo.serve.guard import bracket_host
from stablemo.serve.local import SHUTDOWN_S

DEMO_MODELS = {"student": DEMO_STUDENT, "teacher": DEMO_BUNDLE}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablemo serve", description="Serve a local page and JSON API for generating motions.")
    p.add_argument("--bundle", action="append", metavar="[NAME=]DIR",
                   help="a bundle to serve (repeat for several; the first is the page's default). "
                        "Default: the packaged demo student (1 step) and its teacher (10 steps)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only). The server answers only "
                        "requests whose Host is 127.0.0.1, localhost or [::1] with its port, and this address; "
                        "another address lets other machines in (docs/serve.md: it has no authentication)")
    p.add_argument("--port", type=int, default=7860, help="port (default 7860)")
    p.add_argument("--threads", type=int, default=1,
                   help="torch threads of the one generation worker (default 1: on a 2-core machine shared with "
                        "other work, one thread gave a 1-step motion in ~40 ms against 70-700 ms with two)")
    p.add_argument("--max-queue", type=int, default=32, help="requests allowed to wait before the server answers 503 (default 32)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--no-warmup", action="store_true", help="skip the one generation per model at start-up")
    return p


def bundles_from_args(values: list[str] | None) -> dict[str, Path]:
    if not values:
        found = {name: path for name, path in DEMO_MODELS.items() if (path / "config.json").is_file()}
        if not found:
            raise StableMoError(f"--bundle: no bundle given and the packaged demo models are missing from {ASSETS}")
        return found
    out: dict[str, Path] = {}
    for value in values:
        name, sep, folder = value.partition("=")
        if not sep:
            name, folder = Path(value).name, value
        if not name or not folder:
            raise StableMoError(f"--bundle: {value!r}: expected DIR or NAME=DIR")
        if name in out:
            raise StableMoError(f"--bundle: the name {name!r} is given twice (use NAME=DIR to tell them apart)")
        if not Path(folder).is_dir():
            raise StableMoError(f"--bundle: {folder}: bundle folder not found")
        out[name] = Path(folder)
    return out


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if not 0 < args.port < 65536:
        raise StableMoError(f"--port: must be in [1, 65535], got {args.port}")
    if args.threads < 1:
        raise StableMoError(f"--threads: must be >= 1, got {args.threads}")
    if args.max_queue < 1:
        raise StableMoError(f"--max-queue: must be >= 1, got {args.max_queue}")
    bundles = bundles_from_args(args.bundle)
    _check_port(args.host, args.port)
    from stablemo.serve.vendor import missing

    problem = missing()
    if problem:
        raise StableMoError(problem)
    try:
        import fastapi  # noqa: F401
        import uvicorn
    except ImportError as err:
        raise StableMoError(f"stablemo serve needs FastAPI and uvicorn ({err.name} is not installed): "
                            "pip install -e '.[serve]' (scripts/setup.sh installs them)") from None
    import torch

    torch.set_num_threads(args.threads)
    from stablemo.serve.api import create_app
    from stablemo.serve.models import ModelSet

    models = ModelSet(bundles, device=args.device)
    if not args.no_warmup:  # first-call costs (kernels, allocator) are paid here, not by the first visitor
        for name in models.models:
            models.warm_up(name)
    app = create_app(models, max_queue=args.max_queue, hosts=allowed_hosts(args.host))
    print(f"stablemo serve: {', '.join(models.models)} (default {models.default}) on "
          f"http://{bracket_host(args.host)}:{args.port}/", flush=True)
    if not _is_loopback(args.host):
        print(f"stablemo serve: warning: listening on {args.host}, not this machine only: anyone who can reach "
              f"it can use it (there is no authentication)", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning", timeout_graceful_shutdown=SHUTDOWN_S)
    return 0



def _is_loopback(host: str) -> bool:
    import ipaddress

    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def allowed_hosts(host: str) -> tuple[str, ...]:
    """The names a request's Host may carry: the loopback names, plus --host when it is another
    address; for a wildcard address (0.0.0.0, ::) this machine's host name too, the name other
    machines would use."""
    import ipaddress
    import socket

    from stablemo.serve.guard import LOOPBACK_HOSTS

    names = list(LOOPBACK_HOSTS)
    if not _is_loopback(host):
        names.append(host)
        try:
            wildcard = ipaddress.ip_address(host.strip("[]")).is_unspecified
        except ValueError:
            wildcard = False
        if wildcard:
            names += [socket.gethostname(), socket.getfqdn()]
    return tuple(dict.fromkeys(names))


def _check_port(host: str, port: int) -> None:
    """A taken port or an address not on this machine is one line before the models load."""
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as err:
        raise StableMoError(f"--host: {host}: {err.strerror}") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            sock.bind(address)
        except OSError as err:
            raise StableMoError(f"--port: cannot listen on {host}:{port} ({err.strerror}); is another server running there?") from None
