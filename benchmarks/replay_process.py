"""Whole-process ``clutch replay`` of a one-hour 1 kHz bag against real time.

``python -m benchmarks.replay_process [--bag BAG] [--laws ff_t coulomb] [--repeat 3] [--json]``

Times the real command in a fresh process (``python -m clutch_ros.cli replay BAG --params
flexiforce_8 --law LAW --json``), start-up, read, estimate, summary and exit included, per law,
and prints it as a multiple of the bag's real time (targets of issue 17: >= 1000x with
``ff_t``, >= 500x with ``coulomb``). Baselines from the same run, also whole processes:

- start-up: ``clutch replay --help`` (interpreter, imports, parser);
- read only: a process that reads the bag the way replay does
  (:func:`~clutch_ros.bag.rig_states.read_rig_states` with the replay's fields) and exits;
- not streamed: the same replay with ``--no-stream`` (the whole bag read before the estimate
  starts, one core), beside the default that estimates in a second thread while it reads
  (:mod:`clutch_ros.offline.streaming`);
- numpy model loop (``--numpy-baseline``): the same replay with ``CLUTCH_KERNEL=0``, i.e. the
  numpy reference loop instead of the compiled kernel (:mod:`clutch_ros.model.kernel`).

Every replay process loads the kernel's compiled code from its on-disk cache (included in the
time); only the first run after an install compiles it (~35 s), so the benchmark first runs
one untimed replay per law and prints its time. Each row is the median of ``--repeat`` runs
(default 3).

Wall time [s] and CPU time [s] (user + system of the child) are both printed: on a shared
machine the wall time includes waiting for a core, the CPU time does not.
Without ``--bag`` a one-hour bag is generated (:func:`benchmarks.bag_replay.generate_bag`,
~1 GB, about a minute) into a temporary directory and deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.bag_replay import generate_bag
from clutch_ros.bag.rig_states import REPLAY_FIELDS, read_rig_states

__all__ = ["ProcessRun", "main", "run_process", "TARGETS"]

#: Whole-process replay targets [x real time] per law (issue 17).
TARGETS = {"ff_t": 1000.0, "coulomb": 500.0}


class ProcessRun:
    """One child process: wall and CPU seconds, exit code, stdout."""

    def __init__(self, wall_s: float, cpu_s: float, code: int, out: str, err: str):
        self.wall_s, self.cpu_s, self.code, self.out, self.err = wall_s, cpu_s, code, out, err

    def json(self):
        """Return the child's stdout parsed as JSON."""
        return json.loads(self.out)


def run_process(args: list[str], timeout: float = 1800.0, env_extra: dict | None = None
                ) -> ProcessRun:
    """Run ``python ARGS`` (this interpreter) and time it: wall and child CPU [s]."""
    # the children inherit the numpy settings (benchmarks/__init__.py), the read-only
    # baseline's process included
    env = dict(os.environ, PYTHONUNBUFFERED="1", **(env_extra or {}))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True,
                          timeout=timeout, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {proc.stderr[-500:]}")
    return ProcessRun(wall, cpu, proc.returncode, proc.stdout, proc.stderr)


def _read_only(bag: str) -> int:
    """Child mode: read ``bag`` as replay does, print the sample count."""
    print(len(read_rig_states(Path(bag), fields=REPLAY_FIELDS)))
    return 0


def _median(runs: list[ProcessRun]) -> ProcessRun:
    """Return the run of median wall time."""
    return sorted(runs, key=lambda r: r.wall_s)[len(runs) // 2]


def measure(bag: Path, laws: list[str], numpy_baseline: bool = False, repeat: int = 3
            ) -> dict:
    """Return the figures for ``bag``: baselines and replays per law (and engine).

    Each row is the median (by wall time) of ``repeat`` runs; the rows take turns (every row
    once, then every row again), so a drift of the machine's load touches them alike. First,
    untimed, one replay per law loads (or, the first time after an install, compiles) the
    kernel's machine code into its disk cache; its wall time is kept as ``first_run_s``.
    """
    def replay(law: str, *extra: str) -> list[str]:
        return ["-m", "clutch_ros.cli", "replay", str(bag), "--params", "flexiforce_8",
                "--law", law, "--json", *extra]

    first = {law: run_process(replay(law)).wall_s for law in laws}
    rows: dict[str, tuple[list[str], dict | None]] = {
        "startup": (["-m", "clutch_ros.cli", "replay", "--help"], None),
        "read_only": (["-m", "benchmarks.replay_process", "--read-only", str(bag)], None)}
    for law in laws:
        rows[law] = (replay(law), None)
        rows[f"{law} --no-stream"] = (replay(law, "--no-stream"), None)
    if numpy_baseline:
        rows.update({f"{law} (numpy loop)": (replay(law), {"CLUTCH_KERNEL": "0"})
                     for law in laws})
    runs: dict[str, list[ProcessRun]] = {key: [] for key in rows}
    for _ in range(repeat):
        for key, (args, env_extra) in rows.items():
            runs[key].append(run_process(args, env_extra=env_extra))
    startup, read = _median(runs.pop("startup")), _median(runs.pop("read_only"))
    samples = int(read.out.strip())
    doc = {"bag": str(bag), "samples": samples, "repeat": repeat, "first_run_s": first,
           "startup": {"wall_s": startup.wall_s, "cpu_s": startup.cpu_s},
           "read_only": {"wall_s": read.wall_s, "cpu_s": read.cpu_s}, "replay": {}}
    for key, done in runs.items():
        run = _median(done)
        summary = run.json()[0]
        if summary["samples"] != samples:
            raise RuntimeError(f"replay saw {summary['samples']} of {samples} samples")
        doc["replay"][key] = {"wall_s": run.wall_s, "cpu_s": run.cpu_s,
                              "read_s": summary["read_s"], "estimate_s": summary["estimate_s"],
                              "streamed": summary.get("streamed", False)}
    return doc


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the figures beside their baselines."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.replay_process",
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bag", help="existing 1 kHz RigState bag (default: generate one)")
    parser.add_argument("--seconds", type=float, default=3600.0,
                        help="length of the generated bag [s] (default 3600)")
    parser.add_argument("--rate", type=float, default=1000.0, help="its sample rate [Hz]")
    parser.add_argument("--laws", nargs="+", default=["ff_t", "coulomb"])
    parser.add_argument("--numpy-baseline", action="store_true",
                        help="also replay each law with the numpy model loop (CLUTCH_KERNEL=0)")
    parser.add_argument("--repeat", type=int, default=3,
                        help="runs per row, the median is printed (default 3)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--read-only", metavar="BAG", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.read_only:
        return _read_only(args.read_only)
    with tempfile.TemporaryDirectory(prefix="clutch-bench-") as tmp:
        bag = Path(args.bag) if args.bag else Path(tmp) / "hour"
        if not args.bag:
            generate_bag(bag, args.seconds, args.rate)
        doc = measure(bag, args.laws, args.numpy_baseline, max(1, args.repeat))
    rate = args.rate
    realtime = doc["samples"] / rate  # [s] of rig time in the bag
    doc["realtime_s"] = realtime
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"bag: {doc['samples']} samples = {realtime:g} s of rig time at {rate:g} Hz; "
          f"medians of {doc['repeat']} runs per row")
    print("untimed first replay (loads the compiled kernel; compiles it after an install): "
          + ", ".join(f"{law} {s:.1f} s" for law, s in doc["first_run_s"].items()))
    print(f"{'whole process':36s} {'wall [s]':>9s} {'CPU [s]':>8s} {'x real time (wall)':>19s}")
    rows = [("baseline: start-up (replay --help)", doc["startup"]),
            ("baseline: read only (replay fields)", doc["read_only"])]
    rows += [(f"clutch replay --law {law}", r) for law, r in doc["replay"].items()]
    for label, r in rows:
        print(f"{label:36s} {r['wall_s']:9.2f} {r['cpu_s']:8.2f} "
              f"{realtime / r['wall_s']:18,.0f}x")
    for law, r in doc["replay"].items():
        target = TARGETS.get(law)
        x = realtime / r["wall_s"]
        verdict = "" if target is None else (
            f"; target >= {target:g}x {'met' if x >= target else 'NOT MET'}")
        if r["streamed"]:
            split = (f"read with the estimate overlapped {r['read_s']:.2f} s, rest of the "
                     f"estimate {r['estimate_s']:.2f} s")
        else:
            split = (f"read {r['read_s']:.2f} s, estimate {r['estimate_s']:.2f} s "
                     f"({doc['samples'] / r['estimate_s']:,.0f} samples/s)")
        print(f"  {law}: in-process {split}{verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
