"""Benchmark of the online adaptation: ``python -m benchmarks.adaptation [--repeat R]``.

Prints the time per sample [µs] of :meth:`ClutchEstimator.update` (the baseline, measured in
the same run) and of :meth:`AdaptiveEstimator.update` (friction scale; and with the spline
gain, which runs a shadow estimator), their ratio, and the worst single sample (a new scale
is applied at most once a second and re-discretises the pack: a matrix exponential). Input:
a golden bag's worth of synthetic data: 60 s at 100 Hz of 2 s pressure holds between 8 and
35 bar at 10 rpm, measured torque from the model with μ x 1.1. Medians of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

from benchmarks.model_step import BENCH_PARAMS
from clutch_ros.model import ClutchEstimator, ClutchParams
from clutch_ros.model.adaptation import AdaptationSettings, AdaptiveEstimator, scaled_params

W10 = 10 * 2 * math.pi / 60  # [rad/s]


def _rows(params, n=6000, dt=0.01):
    truth = ClutchEstimator(scaled_params(params, 1.1))
    rows = []
    for i in range(n):
        t = 1.0 + dt * i
        p = (10e5, 25e5, 15e5, 35e5, 8e5, 30e5)[int(dt * i // 2.0) % 6]
        rows.append((t, p, 40.0, W10, truth.update(t, p, 40.0, W10).modelled_torque))
    return rows


def _time(make, rows, repeat):
    per_sample, worst = [], []
    for _ in range(repeat):
        est = make()
        slowest = 0.0
        t0 = time.perf_counter()
        for row in rows:
            s0 = time.perf_counter()
            est.update(*row)
            slowest = max(slowest, time.perf_counter() - s0)
        per_sample.append((time.perf_counter() - t0) / len(rows) * 1e6)
        worst.append(slowest * 1e6)
    return statistics.median(per_sample), statistics.median(worst)


def main(argv=None) -> int:
    """Run the benchmark and print one line per variant."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure (median)")
    parser.add_argument("--samples", type=int, default=6000, help="samples per run (100 Hz)")
    args = parser.parse_args(argv)
    params = ClutchParams.from_flat(BENCH_PARAMS)
    rows = _rows(params, args.samples)
    variants = {
        "ClutchEstimator (baseline)": lambda: ClutchEstimator(params),
        "AdaptiveEstimator, scale": lambda: AdaptiveEstimator(params),
        "AdaptiveEstimator, scale + gain": lambda: AdaptiveEstimator(
            params, AdaptationSettings(spline_gain=True)),
    }
    base = None
    sys.stdout.write(f"{'variant':34s} {'us/sample':>10s} {'x baseline':>10s} "
                     f"{'worst us':>9s}\n")
    for name, make in variants.items():
        us, worst = _time(make, rows, args.repeat)
        base = base or us
        sys.stdout.write(f"{name:34s} {us:10.1f} {us / base:10.2f} {worst:9.0f}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
