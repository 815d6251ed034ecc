"""In-process half of ``python -m benchmarks.live_profile``: thread CPU per call of functions.

A sampling profiler misses much of a live node's CPU: py-spy attributed 6.5 % of a core to the
can_bridge's receive thread while ``/proc`` counted 12.5 % (it samples a thread that runs in
bursts of ~0.3 ms 100-400 times a second, and counts a thread in a C call as waiting), and
``perf`` sees no Python frames on 3.11. This hook counts exactly instead: it wraps the functions
named in the environment variable :data:`ENV` and adds, per call, the calling thread's CPU time
(``time.thread_time_ns``: user + system, the same clock as ``/proc``) while a window is open.

The generated ``sitecustomize.py`` of :mod:`benchmarks.live_profile` calls :func:`install` in
every Python process of the demo; only the node's process (its command line names
``clutch_ros.nodes.<node>``) is hooked. The window opens when the file ``start`` appears in the
control directory and closes at ``stop``; then ``<node>-<pid>.json`` is written there
(:func:`result`). Targets are ``module:Class.method`` or ``module:function``:

* a module imported after :func:`install` is wrapped as its import ends (before anything can
  take a reference to the original), so bound methods kept by timers and threads count too;
* the node's own module runs as ``__main__`` and is wrapped when the window opens: a method
  reached through ``self.<name>`` counts, one bound before (a timer's callback) does not.

Figures are inclusive (a wrapped call inside another counts in both) and each call adds the
wrapper's own ~1 µs. Targets that do not exist are reported under ``errors``.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import json
import os
import sys
import threading
import time
from pathlib import Path

from benchmarks.machine_load import read_stat, stat_cpu

__all__ = ["ENV", "install", "parse_target", "result"]

ENV = "CLUTCH_LIVE_PROFILE"  # JSON: {"node": ..., "targets": [...], "control": dir}
POLL = 0.1  # [s] how often the control thread looks for the start and stop files
_MAIN_PREFIX = "clutch_ros.nodes."


def parse_target(text: str) -> tuple[str, str]:
    """Return ``(module, qualified name)`` of ``module:Class.method`` or ``module:function``."""
    module, sep, qual = text.partition(":")
    parts = qual.split(".")
    if not sep or not module or not qual or len(parts) > 2 or not all(p.isidentifier()
                                                                        for p in parts):
        raise ValueError(f"profile target {text!r}: expected module:Class.method or "
                         "module:function")
    return module, qual


class _Counters:
    """Calls and thread CPU [ns] per target, counted while ``on``."""

    def __init__(self) -> None:
        self.on = False
        self.calls: dict[str, list[int]] = {}
        self.errors: dict[str, str] = {}

    def wrap(self, module, target: str, qual: str) -> None:
        owner_name, _, name = qual.rpartition(".")
        try:
            owner = getattr(module, owner_name) if owner_name else module
            original = getattr(owner, name)
        except AttributeError as err:
            self.errors[target] = str(err)
            return
        counts = self.calls.setdefault(target, [0, 0])
        clock, state = time.thread_time_ns, self

        def counted(*args, **kwargs):
            if not state.on:
                return original(*args, **kwargs)
            start = clock()
            try:
                return original(*args, **kwargs)
            finally:
                counts[0] += 1
                counts[1] += clock() - start

        counted.__wrapped__ = original  # type: ignore[attr-defined]
        setattr(owner, name, counted)


class _Finder(importlib.abc.MetaPathFinder):
    """Wraps the targets of a module as soon as its import has run."""

    def __init__(self, counters: _Counters, targets: dict[str, list[tuple[str, str]]]) -> None:
        self._counters, self._targets = counters, targets

    def find_spec(self, name, path, target=None):
        if name not in self._targets:
            return None
        sys.meta_path.remove(self)  # the real finders find it
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None:
            return spec
        run_module, counters, wanted = spec.loader.exec_module, self._counters, self._targets
        loader = spec.loader

        def exec_module(module):
            run_module(module)
            for target, qual in wanted[name]:
                counters.wrap(module, target, qual)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


def _process_cpu() -> float:
    return time.process_time()  # [s] every thread of the process, user + system


def _thread_cpu() -> dict[int, tuple[str, float]]:
    """Return ``{thread id: (name, CPU [s])}`` of this process's threads (``/proc``)."""
    names, out = {t.native_id: t.name for t in threading.enumerate()}, {}
    for task in Path("/proc/self/task").iterdir():
        stat = read_stat(task / "stat")
        if stat is not None:
            tid = int(task.name)
            out[tid] = (names.get(tid, stat[0]), stat_cpu(stat[1]))
    return out


def result(counters: _Counters, window_s: float, process_s: float,
           threads: dict[str, float]) -> dict:
    """Return the JSON written at the end of the window (see the module docstring)."""
    calls = {target: {"calls": n, "cpu_s": ns * 1e-9} for target, (n, ns)
             in counters.calls.items()}
    return {"pid": os.getpid(), "window_s": window_s, "process_cpu_s": process_s,
            "threads_cpu_s": threads, "targets": calls, "errors": counters.errors}


def _control(counters: _Counters, control: Path, node: str,
             main_targets: list[tuple[str, str]]) -> None:
    while not (control / "start").exists():
        time.sleep(POLL)
    main = sys.modules.get("__main__")
    for target, qual in main_targets:
        counters.wrap(main, target, qual)
    threads0, cpu0, t0 = _thread_cpu(), _process_cpu(), time.monotonic()
    counters.on = True
    while not (control / "stop").exists():
        time.sleep(POLL)
    counters.on = False
    threads1, cpu1, t1 = _thread_cpu(), _process_cpu(), time.monotonic()
    threads = {}
    for tid, (name, cpu) in threads1.items():
        before = threads0.get(tid, (name, 0.0))[1]
        key = name if name not in threads else f"{name} ({tid})"
        threads[key] = cpu - before
    out = result(counters, t1 - t0, cpu1 - cpu0, threads)
    path = control / f"{node}-{os.getpid()}.json"
    path.with_suffix(".tmp").write_text(json.dumps(out, indent=1))
    path.with_suffix(".tmp").replace(path)


def install() -> bool:
    """Install the hook in this process if it is the node named in :data:`ENV` (True then)."""
    spec = os.environ.get(ENV)
    if not spec:
        return False
    config = json.loads(spec)
    node = config["node"]
    try:
        argv = Path("/proc/self/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    if f"{_MAIN_PREFIX}{node}".encode() not in argv:
        return False
    counters = _Counters()
    by_module: dict[str, list[tuple[str, str]]] = {}
    main_targets = []
    for target in config["targets"]:
        module, qual = parse_target(target)
        if module in ("__main__", f"{_MAIN_PREFIX}{node}"):
            main_targets.append((target, qual))
        else:
            by_module.setdefault(module, []).append((target, qual))
    for module in list(by_module):  # imported already (by site or this hook): wrap now
        if module in sys.modules:
            for target, qual in by_module.pop(module):
                counters.wrap(sys.modules[module], target, qual)
    sys.meta_path.insert(0, _Finder(counters, by_module))
    threading.Thread(target=_control, name="live_profile",
                     args=(counters, Path(config["control"]), node, main_targets),
                     daemon=True).start()
    return True
