"""``clutch replay --jobs N`` against the serial run of the same bags.

``python -m benchmarks.batch_replay [--bags BAG...] [--count 4] [--seconds 300] [--jobs 2]``

Replays the same bags (default: four generated 5-minute 1 kHz RigState bags) with the real
command in a fresh process, serially and with ``--jobs N``, and prints both wall times, the
ratio (issue 17's target on a 2-core machine: ``--jobs 2`` <= 0.7x serial) and whether the
per-bag figures are identical (timings aside). CPU time (user + system of the process and its
workers) is printed too: on a shared machine the wall time includes waiting for a core.
``--repeat`` alternates the runs that many times and keeps each one's fastest.

More baselines from the same run: ``--no-stream`` (the serial run on one core: by default a
serial replay estimates each bag in a second thread while it is read, so "serial" already
uses up to two cores), the start-up (a replay of a 0.1 s bag: imports, the compiled
kernel's load, the first bag's set-up), and from them the best ``--jobs N`` could do: the
start-up once plus the one-core bag time shared out N ways. With four 5-minute bags the
start-up (~0.75 s) is half of the run, which bounds the ratio near 0.75x whatever the
parallelism.

Second baseline, same run: the parallelism the machine offers right now. A fixed pure-Python
CPU loop is run four times serially and by two worker processes; on an idle 2-core machine
that ratio is ~0.5, on a machine whose cores are busy with other work it approaches 1, and
``--jobs`` cannot do better than it.

CPU figures, for a shared machine (where wall time includes waiting for a core): the CPU
seconds summed over the replay process and its workers (``--jobs N`` against the one-core
``--no-stream`` run), and the critical path: the parent's own CPU (start-up, set-up, the
results; all counted as serial, an upper bound) plus the busiest worker's CPU. On an idle
N-core machine the ``--jobs N`` wall time is about the critical path, so
``critical path / one-core CPU`` predicts the wall ratio. Each worker's CPU is sampled from
``/proc/PID/stat`` every few milliseconds while it runs (Linux; only the replay's children,
found through ``/proc/PID/task/TID/children``; the last few milliseconds of a worker are
missed and counted as the parent's, which makes the critical path longer).
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
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from benchmarks.bag_replay import generate_bag
from benchmarks.machine_load import read_stat, stat_cpu
from benchmarks.replay_process import ProcessRun, run_process

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


#: Seconds between two samples of the workers' CPU times.
_POLL_S = 0.005


def _proc_cpu(pid: int) -> tuple[int, float] | None:
    """Return ``(parent pid, user + system CPU [s])`` of ``pid`` from /proc, None if gone."""
    stat = read_stat(f"/proc/{pid}/stat")
    return None if stat is None else (int(stat[1][1]), stat_cpu(stat[1]))


def _children(pid: int) -> list[int]:
    """Return the child processes of ``pid``: its threads' ``children`` lists in /proc.

    Reading only those (not every process's stat) keeps the poll cheap: a scan of all of
    /proc every few milliseconds takes CPU from the replay it measures on a busy machine.
    Falls back to the scan where the kernel has no ``children`` files.
    """
    try:
        threads = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return []
    found: list[int] = []
    for tid in threads:
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                found.extend(int(c) for c in f.read().split())
        except FileNotFoundError:  # no CONFIG_PROC_CHILDREN, or the thread ended
            if not os.path.exists(f"/proc/{pid}/task/{tid}"):
                continue
            return [int(n) for n in os.listdir("/proc") if n.isdigit()]
        except OSError:
            continue
    return found


def run_polled(args: list[str], timeout: float = 1800.0) -> tuple[ProcessRun, list[float]]:
    """Run ``python ARGS`` like :func:`run_process`; also return each child's CPU [s].

    The child processes of the replay (its pool workers) are found and sampled in /proc
    every :data:`_POLL_S` while the replay runs; each worker's last sample is kept.
    """
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    workers: dict[int, float] = {}
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, *args], stdout=out, stderr=err, text=True,
                                env=env)
        while proc.poll() is None:
            if time.perf_counter() - start > timeout:
                proc.kill()
                proc.wait()
                raise RuntimeError(f"{' '.join(args)} timed out after {timeout} s")
            for pid in _children(proc.pid):
                if (found := _proc_cpu(pid)) is not None and found[0] == proc.pid:
                    workers[pid] = found[1]
            time.sleep(_POLL_S)
        wall = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {stderr[-500:]}")
    return ProcessRun(wall, cpu, proc.returncode, stdout, stderr), sorted(workers.values())


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
        tiny = Path(tmp) / "tiny"  # 0.1 s: a replay that is all start-up and one-time loads
        generate_bag(tiny, 0.1)
        best: dict[str, object] = {}
        spare = []
        polled: list[tuple[float, list[float]]] = []  # (CPU, per-worker CPU) of --jobs runs
        variants = {"serial": cmd, "one_core": [*cmd, "--no-stream"],
                    "parallel": [*cmd, "--jobs", str(args.jobs)],
                    "startup": [*cmd[:3], str(tiny), *cmd[3 + len(bags):]]}
        for _ in range(max(args.repeat, 1)):
            spare.append(spare_parallelism(args.jobs))
            for key, argv_ in variants.items():  # in turn, each kept at its fastest
                if key == "parallel":
                    run, worker_cpu = run_polled(argv_)
                    polled.append((run.cpu_s, worker_cpu))
                else:
                    run = run_process(argv_)
                if key not in best or run.wall_s < best[key].wall_s:
                    best[key] = run
        serial, parallel, one_core = best["serial"], best["parallel"], best["one_core"]
        identical = _figures(serial) == _figures(parallel) == _figures(one_core)
        samples = sum(r["samples"] for r in serial.json())
    ratio = parallel.wall_s / serial.wall_s
    # CPU: the --jobs run of least total CPU; its parent's own CPU is all counted as serial
    total_cpu, worker_cpu = min(polled, key=lambda p: p[0])
    parent_cpu = total_cpu - sum(worker_cpu)
    critical = parent_cpu + max(worker_cpu, default=0.0)
    # what --jobs could reach at best: the start-up once, the bags' one-core time shared out
    startup = best["startup"].wall_s
    ideal = startup + (one_core.wall_s - startup) / args.jobs
    doc = {"bags": len(bags), "samples": samples, "jobs": args.jobs, "law": args.law,
           "serial_wall_s": serial.wall_s, "serial_cpu_s": serial.cpu_s,
           "one_core_wall_s": one_core.wall_s, "startup_wall_s": startup,
           "parallel_wall_s": parallel.wall_s, "parallel_cpu_s": parallel.cpu_s,
           "ratio": ratio, "ratio_one_core": parallel.wall_s / one_core.wall_s,
           "ideal_ratio": ideal / serial.wall_s, "identical": identical,
           "cpu_loop_ratio": min(spare), "one_core_cpu_s": one_core.cpu_s,
           "parallel_total_cpu_s": total_cpu, "parallel_parent_cpu_s": parent_cpu,
           "parallel_worker_cpu_s": worker_cpu, "critical_path_cpu_s": critical,
           "cpu_ratio_total": total_cpu / one_core.cpu_s,
           "cpu_ratio_critical": critical / one_core.cpu_s}
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"{len(bags)} bags, {samples} samples, law {args.law}, whole `clutch replay` process")
    print(f"baseline: serial          wall {serial.wall_s:7.2f} s  CPU {serial.cpu_s:7.2f} s"
          "  (each bag's estimate streamed beside its read: up to two cores)")
    print(f"baseline: --no-stream     wall {one_core.wall_s:7.2f} s  "
          f"CPU {one_core.cpu_s:7.2f} s  (one core)")
    print(f"baseline: start-up        wall {startup:7.2f} s  (a replay of a 0.1 s bag: "
          "imports, the kernel's load, the first bag's set-up)")
    print(f"--jobs {args.jobs:<2d}                 wall {parallel.wall_s:7.2f} s  "
          f"CPU {parallel.cpu_s:7.2f} s  ({parallel.wall_s / one_core.wall_s:.2f}x the "
          "one-core run)")
    print(f"best --jobs {args.jobs} can do: start-up + one-core bag time / {args.jobs} = "
          f"{ideal:.2f} s = {ideal / serial.wall_s:.2f}x serial")
    print(f"baseline: pure-Python CPU loop, {args.jobs} processes vs serial: "
          f"{min(spare):.2f}x (best of {len(spare)}; the parallelism this machine has to spare)")
    print(f"CPU --jobs {args.jobs}: total {total_cpu:.2f} s = {total_cpu / one_core.cpu_s:.2f}x "
          f"the one-core CPU {one_core.cpu_s:.2f} s; parent {parent_cpu:.2f} s, workers "
          + ", ".join(f"{w:.2f}" for w in worker_cpu) + " s")
    print(f"CPU critical path (parent + busiest worker) {critical:.2f} s = "
          f"{critical / one_core.cpu_s:.2f}x the one-core CPU (~ the wall ratio on an idle "
          f"{args.jobs}-core machine; issue 23's target <= 0.6x)")
    print(f"ratio {ratio:.2f}x serial (target <= {TARGET_RATIO:g}x: "
          f"{'met' if ratio <= TARGET_RATIO else 'NOT MET'}); per-bag figures identical: "
          f"{'yes' if identical else 'NO'}")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
