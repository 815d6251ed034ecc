"""``clutch replay --jobs N`` against the serial run of the same bags.

``python -m benchmarks.batch_replay [--bags BAG...] [--count 4] [--seconds 300] [--jobs 2]``

Replays the same bags (default: four generated 5-minute 1 kHz RigState bags) with the real
command in a fresh process, serially and with ``--jobs N``, and prints both wall times, the
ratio (issue 17's target on a 2-core machine: ``--jobs 2`` <= 0.7x serial) and whether the
per-bag figures are identical (timings aside). CPU time (user + system of the process and its
workers) is printed too: on a shared machine the wall time includes waiting for a core.
``--repeat`` alternates the two runs that many times and keeps each one's fastest.

Second baseline, same run: the parallelism the machine offers right now. A fixed pure-Python
CPU loop is run four times serially and by two worker processes; on an idle 2-core machine
that ratio is ~0.5, on a machine whose cores are busy with other work it approaches 1, and
``--jobs`` cannot do better than it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from benchmarks.bag_replay import generate_bag
from benchmarks.replay_process import run_process

__all__ = ["TARGET_RATIO", "main"]

#: Target: parallel wall time / serial wall time (issue 17, 2 cores, --jobs 2).
TARGET_RATIO = 0.7
_TIMINGS = {"seconds", "samples_per_s", "read_s", "estimate_s", "streamed", "streamed_pieces"}


def _spin(_: int) -> int:
    """Do a fixed amount of pure-Python CPU work (~1 s); return its sum."""
    total = 0
    for i in range(15_000_000):
        total += i
    return total


def spare_parallelism(jobs: int) -> float:
    """Wall time of 2 x ``jobs`` CPU loops in ``jobs`` processes / serially (same run)."""
    start = time.perf_counter()
    for i in range(2 * jobs):
        _spin(i)
    serial = time.perf_counter() - start
    start = time.perf_counter()
    with ProcessPoolExecutor(jobs) as pool:
        list(pool.map(_spin, range(2 * jobs)))
    return (time.perf_counter() - start) / serial


def _figures(run) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in _TIMINGS} for r in run.json()]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print parallel vs serial."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.batch_replay",
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bags", nargs="+", help="existing bags (default: generate --count)")
    parser.add_argument("--count", type=int, default=4, help="bags to generate (default 4)")
    parser.add_argument("--seconds", type=float, default=300.0, help="length of each [s]")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--law", default="ff_t")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="clutch-bench-") as tmp:
        bags = [Path(b) for b in args.bags] if args.bags else []
        for i in range(0 if args.bags else args.count):
            bags.append(Path(tmp) / f"bag{i}")
            generate_bag(bags[-1], args.seconds)
        cmd = ["-m", "clutch_ros.cli", "replay", *map(str, bags), "--params", "flexiforce_8",
               "--law", args.law, "--json"]
        serial = parallel = None
        spare = []
        for _ in range(max(args.repeat, 1)):
            spare.append(spare_parallelism(args.jobs))
            s = run_process(cmd)
            p = run_process([*cmd, "--jobs", str(args.jobs)])
            serial = s if serial is None or s.wall_s < serial.wall_s else serial
            parallel = p if parallel is None or p.wall_s < parallel.wall_s else parallel
        identical = _figures(serial) == _figures(parallel)
        samples = sum(r["samples"] for r in serial.json())
    ratio = parallel.wall_s / serial.wall_s
    doc = {"bags": len(bags), "samples": samples, "jobs": args.jobs, "law": args.law,
           "serial_wall_s": serial.wall_s, "serial_cpu_s": serial.cpu_s,
           "parallel_wall_s": parallel.wall_s, "parallel_cpu_s": parallel.cpu_s,
           "ratio": ratio, "identical": identical, "cpu_loop_ratio": min(spare)}
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"{len(bags)} bags, {samples} samples, law {args.law}, whole `clutch replay` process")
    print(f"baseline: serial          wall {serial.wall_s:7.2f} s  CPU {serial.cpu_s:7.2f} s")
    print(f"--jobs {args.jobs:<2d}                 wall {parallel.wall_s:7.2f} s  "
          f"CPU {parallel.cpu_s:7.2f} s")
    print(f"baseline: pure-Python CPU loop, {args.jobs} processes vs serial: "
          f"{min(spare):.2f}x (best of {len(spare)}; the parallelism this machine has to spare)")
    print(f"ratio {ratio:.2f}x serial (target <= {TARGET_RATIO:g}x: "
          f"{'met' if ratio <= TARGET_RATIO else 'NOT MET'}); per-bag figures identical: "
          f"{'yes' if identical else 'NO'}")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
