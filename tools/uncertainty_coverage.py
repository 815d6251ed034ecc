"""Coverage table of the torque uncertainty band (issue 24): fit on one run, validate on others.

    .venv/bin/python tools/uncertainty_coverage.py [--fit table3_seq2_10rpm[,run...]]
        [--sim-seeds 2] [--plant rig_truth_elastic] [--params flexiforce_8] [--no-golden]

Runs: the golden bags (tests/data/golden/bags) and, with ``--sim-seeds N``, N fresh runs of
the simulated rig (truth plant ``--plant``, default the golden bags' ``rig_truth_elastic``)
per golden scenario with other noise seeds (seed + 1000 * k). The error model is fitted on
the ``--fit`` golden run(s) only (comma-separated, joined as ``fit_error_model_on_bags``
does); the table lists every other run (never a fitted one).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import uncertainty as unc
from clutch_ros.offline.golden import PLANT
from clutch_ros.offline.replay import fit_error_model_on_bags, replay_bag, stamps_s
from clutch_ros.offline.rig_runs import GOLDEN_RUNS, golden_scenario, simulate_run, write_run

GOLDEN = Path(__file__).resolve().parents[1] / "tests" / "data" / "golden" / "bags"


def _series(bag: Path, params):
    result = replay_bag(bag, params, per_lamella=False, pipeline=False)
    b = result.batch
    return (stamps_s(result.rig), b.modelled_torque, b.measured_torque,
            b.slip_speed_filtered, b.actuating_pressure)


def main() -> int:
    """Print (or ``--json``) the coverage table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fit", default="table3_seq2_10rpm")
    ap.add_argument("--params", default="flexiforce_8",
                    help="estimator parameters: a preset or a YAML file (e.g. of clutch fit)")
    ap.add_argument("--sim-seeds", type=int, default=0)
    ap.add_argument("--plant", default=PLANT,
                    help=f"truth plant of the simulated runs (default {PLANT}, the golden bags')")
    ap.add_argument("--no-golden", action="store_true", help="list simulated runs only")
    ap.add_argument("--time-constant", type=float, default=unc.DEFAULTS.time_constant,
                    help="rate filter time constant of the error model [s]")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    params = load_params(preset_path(args.params))
    fitted = args.fit.split(",")
    base = replace(unc.DEFAULTS, time_constant=args.time_constant)
    model = fit_error_model_on_bags([GOLDEN / name for name in fitted], params, base)
    rows = []
    runs = [] if args.no_golden else [(name, GOLDEN / name) for name in GOLDEN_RUNS
                                      if name not in fitted]
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(1, args.sim_seeds + 1):
            for name in GOLDEN_RUNS:
                scenario, seed = golden_scenario(name)
                run = simulate_run(scenario, seed=seed + 1000 * k, wheel_speeds=False,
                                   plant=args.plant)
                path = Path(tmp) / f"{name}_seed{seed + 1000 * k}"
                write_run(path, run)
                runs.append((path.name, path))
        for name, bag in runs:
            t, mod, meas, slip, p = _series(bag, params)
            std = unc.torque_std(model, t, mod, slip)
            cov = unc.coverage(meas, mod, std, unc.phases(t, p, slip))
            rows.append({"run": name, **cov})
    if args.json:
        json.dump({"model": model.to_flat(), "runs": rows}, sys.stdout, indent=1)
        return 0
    sys.stdout.write(f"error model fitted on {args.fit}: {model.to_flat()}\n")
    sys.stdout.write(f"{'run':32s} {'all':>6s} {'trans':>6s} {'steady':>6s}  n_trans/n\n")
    for r in rows:
        sys.stdout.write(f"{r['run']:32s} {100 * r['coverage_95']:6.1f} "
                         f"{100 * r['coverage_95_transient']:6.1f} "
                         f"{100 * r['coverage_95_steady']:6.1f}  "
                         f"{r['coverage_transient_samples']}/{r['coverage_samples']}\n")
    def within(value, low, high):  # a phase without samples (NaN) has nothing to meet
        return math.isnan(value) or low <= 100 * value <= high

    ok = [within(r["coverage_95"], 90, 98) and within(r["coverage_95_transient"], 85, 99)
          and within(r["coverage_95_steady"], 85, 99) for r in rows]
    sys.stdout.write(f"runs meeting the issue-24 bounds (a phase without samples: n/a): "
                     f"{sum(ok)}/{len(ok)}\n")
    worst = np.array([[r["coverage_95"], r["coverage_95_transient"], r["coverage_95_steady"]]
                      for r in rows])
    sys.stdout.write(f"min all/trans/steady: {np.nanmin(worst, axis=0).round(3)}  "
                     f"max: {np.nanmax(worst, axis=0).round(3)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
