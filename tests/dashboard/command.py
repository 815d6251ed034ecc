"""Run ``clutch dashboard`` as a subprocess on a free port, as the tests' server."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from contextlib import contextmanager

from tests.conftest import REPO


def free_port() -> int:
    """Return a TCP port free on 127.0.0.1 now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def dashboard_command(*args: str, env: dict | None = None, ready: str = "serving"):
    """Start ``clutch dashboard ARGS --port P``; yield (url, output lines); SIGINT at the end.

    Its output (stdout and stderr) is collected line by line; the command is ready once a
    line contains ``ready``. On the way out it must exit 0 after SIGINT.
    """
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "clutch_ros.cli", "dashboard", *args,
                             "--port", str(port)], cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    started = threading.Event()

    def pump():
        for line in proc.stdout:
            lines.append(line)
            if ready in line:
                started.set()

    threading.Thread(target=pump, daemon=True).start()
    try:
        assert started.wait(60), "".join(lines)
        yield f"ws://127.0.0.1:{port}", lines
    finally:
        proc.send_signal(2)  # SIGINT: the server closes, exit 0
        proc.wait(20)
    assert proc.returncode == 0, "".join(lines)
