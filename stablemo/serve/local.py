"""Run the app on a loopback port inside this process (tests, the latency and load scripts)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

# on SIGTERM/Ctrl-C, requests still running (a long stream, a download waiting for its file) are
# cancelled after this many seconds instead of being waited for; the worker threads are daemons
SHUTDOWN_S = 0.3


@contextlib.contextmanager
def serving(app, host: str = "127.0.0.1", port: int = 0, timeout: float = 30.0) -> Iterator[str]:
    """Serve `app` with uvicorn on a thread; yields its base URL ("http://127.0.0.1:PORT"), port 0
    = a free one. The server stops when the block ends."""
    import uvicorn

    # as `stablemo serve`: requests still running when the block ends are cancelled, not waited for
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning", lifespan="on",
                                           timeout_graceful_shutdown=SHUTDOWN_S))
    thread = threading.Thread(target=server.run, name="stablemo-serve", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError(f"uvicorn did not start on {host}:{port}")
        time.sleep(0.02)
    bound = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://{host}:{bound}"
    finally:
        server.should_exit = True
        thread.join(timeout)
