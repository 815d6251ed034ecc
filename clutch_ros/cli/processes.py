"""Start and stop the suite's nodes as separate OS processes (used by ``clutch demo``).

Each node runs as ``python -m clutch_ros.nodes.<name> --ros-args ...`` with its stdout and
stderr in ``<run dir>/logs/<name>.log``. Stopping sends SIGINT (the nodes shut down cleanly,
closing buses and bags), then SIGTERM, then SIGKILL if a node does not exit in time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from clutch_ros.errors import ClutchError

__all__ = ["NodeProcess", "isolated_ros_env", "node_env", "ros_param_args"]


def ros_param_args(params: dict) -> list[str]:
    """Return ``-p name:=value`` arguments for ``params`` (lists as YAML flow sequences)."""
    out = []
    for name, value in params.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, (list, tuple)):
            text = "[" + ", ".join(repr(v) if isinstance(v, str) else str(v) for v in value) + "]"
        else:
            text = str(value)
        out += ["-p", f"{name}:={text}"]
    return out


def isolated_ros_env(domain_id: int) -> dict:
    """Environment for child nodes: loopback discovery and a private ROS domain."""
    env = node_env()
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(domain_id)
    return env


def node_env() -> dict:
    """Environment for child nodes in this process's ROS graph (domain, discovery as set)."""
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    source_root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = source_root + os.pathsep + env.get("PYTHONPATH", "")
    return env


class NodeProcess:
    """One node in its own process; ``stop()`` shuts it down cleanly and returns its code."""

    def __init__(self, name: str, args: list[str], env: dict, log_dir: Path,
                 executable: str | None = None, own_session: bool = True):
        """Start ``clutch_ros.nodes.<executable>`` (default: ``name``), logging to log_dir.

        ``name`` names the log file (``<name>.log``) and the node in messages. The node never
        gets the terminal's Ctrl-C (its own process group; ``stop()`` ends it in order).
        ``own_session`` (default) also gives it a session of its own, and so, on Linux with
        ``autogroup`` scheduling (the default of most kernels, and of this machine's), a CPU
        share of its own: the scheduler first splits a busy machine equally between sessions,
        then between the processes in each. False keeps it in this process's session.
        """
        self.name = name
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f"{name}.log"
        restart = 1
        while self.log_path.exists():  # a restarted node keeps the earlier log
            restart += 1
            self.log_path = log_dir / f"{name}.{restart}.log"
        self._log = open(self.log_path, "w")  # noqa: SIM115 - closed in stop()
        cmd = [sys.executable, "-m", f"clutch_ros.nodes.{executable or name}", *args]
        try:
            group = {"start_new_session": True} if own_session else {"process_group": 0}
            self._proc = subprocess.Popen(cmd, env=env, stdout=self._log,
                                          stderr=subprocess.STDOUT, **group)
        except OSError as err:
            self._log.close()
            raise ClutchError(f"cannot start node {name}: {err}") from err

    @property
    def returncode(self) -> int | None:
        """Exit code once the process has ended (None while it runs)."""
        return self._proc.poll()

    @property
    def pid(self) -> int:
        """Process id of the node."""
        return self._proc.pid

    def alive(self) -> bool:
        """Return True while the process runs."""
        return self._proc.poll() is None

    def tail(self, lines: int = 15) -> str:
        """Return the last ``lines`` lines of the node's log."""
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def kill(self) -> None:
        """Kill the process at once (SIGKILL), as a crash would."""
        if self.alive():
            self._proc.kill()
            self._proc.wait()

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then SIGTERM, then SIGKILL; return the exit code."""
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 3.0),
                          (signal.SIGKILL, 3.0)):
            if not self.alive():
                break
            try:
                self._proc.send_signal(sig)
                self._proc.wait(wait)
            except subprocess.TimeoutExpired:
                continue
        self._log.close()
        return self._proc.returncode if self._proc.returncode is not None else -9
