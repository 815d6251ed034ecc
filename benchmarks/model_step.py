"""Benchmark of the model core: ``python -m benchmarks.model_step [--lamellas N]``.

For each spline law it prints the time per :meth:`PackModel.step` call [µs] and the cost of
:func:`simulate` per sample [µs] with the numpy reference loop (``engine="numpy"``, the
same-run baseline) and with the compiled kernel (``engine="kernel"``,
:mod:`clutch_ros.model.kernel`), each also as a ratio to real time at the sample rate, and the
kernel's speed-up over numpy, and the kernel called for one sample at a time (what a node
would pay per message on the kernel path instead of ``step()``: the call's set-up, not the
arithmetic, dominates there). Input: Table 3 at 10 rpm (step, incremented step, 4/12/24 s
ramps, with lead-in/out), sampled at 1 ms, with the ``flexiforce_8`` parameters (N and law
overridden). Each figure is the median of ``--repeat`` runs, the engines interleaved within a
run (wall clock, one core). Excluded from timing: the first discretisation and the kernel's
compilation / cache load (one untimed simulate() per engine first).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from clutch_ros.model.pack import PackModel
from clutch_ros.model.params import SPLINE_LAWS, ClutchParams
from clutch_ros.model.sequences import concatenate, table3
from clutch_ros.model.simulate import simulate, simulate_columns

#: flexiforce_8 (params/flexiforce_8.yaml) as a dict, so the benchmark needs no YAML.
BENCH_PARAMS = {
    "clutch.lamella_count": 8, "clutch.effective_radius": 0.045, "clutch.piston_area": 3.75e-3,
    "clutch.lamella_mass": 0.1, "clutch.lamella_stiffness": 4.0e8,
    "clutch.lamella_damping": 4.0e7, "friction.mu_ref": 0.12, "friction.temperature_ref": 35.0,
    "friction.temperature_slope": -0.0015, "friction.pressure_loss_at_ref": 0.05,
    "friction.pressure_ref": 4.0e6, "friction.static_ratio": 1.15,
    "friction.stribeck_speed": 0.5, "spline.law": "ff_t", "spline.gain": 0.3786,
    "spline.time_constant": 0.9434,
}
LAWS = tuple(SPLINE_LAWS)  # every registered law (clutch_ros/model/laws.py)
ENGINES = ("numpy", "kernel")


def bench_law(params, seq, repeat: int, step_samples: int) -> tuple[float, dict]:
    """Return (µs per step(), {engine: simulate() µs per sample}), medians of ``repeat``."""
    t, p, w, temp = seq.t, seq.actuating_pressure, seq.slip_speed, seq.lamella_temperature
    n = min(step_samples, t.size - 1)
    dts = np.diff(t).tolist()
    pl, wl, tl = p.tolist(), w.tolist(), temp.tolist()
    model = PackModel(params)
    for engine in ENGINES:  # untimed: discretisation cache, kernel compilation / cache load
        simulate(params, t, p, w, temp, model=model, engine=engine)
    step_us, sim_us = [], {engine: [] for engine in ENGINES}
    for _ in range(repeat):
        model.reset(pl[0], tl[0], wl[0])
        step = model.step
        t0 = time.perf_counter()
        for k in range(1, n + 1):
            step(dts[k - 1], pl[k], wl[k], tl[k])
        step_us.append((time.perf_counter() - t0) / n * 1e6)
        for engine in ENGINES:
            t0 = time.perf_counter()
            simulate(params, t, p, w, temp, model=model, engine=engine)
            sim_us[engine].append((time.perf_counter() - t0) / t.size * 1e6)
    single_us = []  # the kernel, one sample per call (pairs of samples, no reset)
    out, calls = np.empty((10, 2)), min(n, 3000)
    for _ in range(repeat):
        model.reset(pl[0], tl[0], wl[0])
        t0 = time.perf_counter()
        for k in range(1, calls + 1):
            ran = simulate_columns(params, t[k - 1:k + 1], p[k - 1:k + 1], w[k - 1:k + 1],
                                   temp[k - 1:k + 1], out, model=model, reset=False,
                                   engine="kernel")
        # the output loop has no code for the printed laws (simulate() runs them): no figure
        single_us.append((time.perf_counter() - t0) / calls * 1e6 if ran else float("nan"))
    sim_us["kernel, one sample per call"] = single_us
    return (statistics.median(step_us),
            {engine: statistics.median(v) for engine, v in sim_us.items()})


def main(argv=None) -> int:
    """Run the benchmark and print one line per law."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.model_step",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--lamellas", type=int, default=8, help="N (default 8)")
    parser.add_argument("--repeat", type=int, default=5, help="runs per figure (median)")
    parser.add_argument("--step-samples", type=int, default=30000,
                        help="step() calls per run (default 30000)")
    parser.add_argument("--dt", type=float, default=1e-3, help="sample time [s]")
    args = parser.parse_args(argv)
    base = ClutchParams.from_flat({**BENCH_PARAMS, "clutch.lamella_count": args.lamellas})
    seq = concatenate(table3(10.0, args.dt), "table3_10rpm")
    rate = 1.0 / args.dt
    print(f"clutch_ros.model benchmark: N = {args.lamellas}, dt = {args.dt * 1e3:g} ms, "
          f"input Table 3 at 10 rpm ({seq.t.size} samples, {seq.t[-1]:.1f} s), "
          f"median of {args.repeat}")
    print(f"{'law':12s} {'step() [us]':>11s} {'step xRT':>9s} | {'simulate numpy [us]':>19s} "
          f"{'xRT':>6s} | {'simulate kernel [us]':>20s} {'xRT':>7s} | {'speed-up':>8s} | "
          f"{'kernel 1/call [us]':>18s}")
    for law in LAWS:
        params = base.with_law(law)
        step_us, sim_us = bench_law(params, seq, args.repeat, args.step_samples)
        num, ker = sim_us["numpy"], sim_us["kernel"]
        print(f"{law:12s} {step_us:11.2f} {1e6 / step_us / rate:9.0f} | {num:19.3f} "
              f"{1e6 / num / rate:6.0f} | {ker:20.3f} {1e6 / ker / rate:7.0f} | "
              f"{num / ker:7.1f}x | {sim_us['kernel, one sample per call']:18.2f}")
    print("targets: step() <= 30 us, simulate() >= 500x real time at 1 kHz; "
          "arithmetic limit ~1 us per step (N = 8)")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
