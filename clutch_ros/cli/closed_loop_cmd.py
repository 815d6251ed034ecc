"""``clutch closed-loop``: the controller on the simulated rig, offline and deterministic.

Runs the truth plant (``--rig-params``), the estimator and the controller
(:mod:`clutch_ros.offline.closed_loop`) over the demo's torque-request profile without ROS or a
bus: the default (adaptive estimator, controller on the adapted model with the integral
torque trim), the feed-forward path of ``clutch demo --no-adapt`` (no adaptation, no trim)
and, for comparison, the feed-forward path without the request lead and without the
spline-friction correction. Prints the fraction of settled time within ±10 % of the request,
the worst overshoot, the longest stretch above 1.1 and the steady-state error (the largest
|mean measured / request − 1| over the last 0.5 s of every plateau ≥ 1 s and ≥ 10 % of the
rated torque).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

from clutch_ros.cli.dispatch import emit_json
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.errors import ClutchError
from clutch_ros.model import reference_torque
from clutch_ros.model.adaptation import AdaptationSettings
from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.offline.closed_loop import run_closed_loop
from clutch_ros.rig import RigPlant
from clutch_ros.rig.request_profile import demo_profile

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    """Register ``clutch closed-loop``."""
    p = sub.add_parser("closed-loop", help="offline closed loop of the controller on the "
                       "simulated rig", description=__doc__.split("\n\n")[0])
    p.add_argument("--params", default="flexiforce_8",
                   help="estimator/controller parameter preset or YAML (default flexiforce_8)")
    p.add_argument("--rig-params", default="rig_truth",
                   help="truth-plant preset or YAML (default rig_truth)")
    p.add_argument("--full", action="store_true", help="the full demo profile (default quick)")
    p.add_argument("--delay", type=float, default=0.0,
                   help="transport delay from command to pump [s] (default 0; live on a "
                        "loaded 2-core PC 0.02-0.1 s)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    """Run the three variants and print their figures."""
    if not (math.isfinite(args.delay) and 0.0 <= args.delay <= 1.0):
        raise ClutchError(f"--delay must be within 0..1 s, got {args.delay}")
    params = load_params(preset_path(args.params))
    rig_file = preset_path(args.rig_params)
    rated = float(reference_torque(params, 40e5, 35.0, 10 * 2 * math.pi / 60))
    profile = demo_profile(rated, quick=not args.full)
    base = ControllerSettings()
    rows = {}
    adapt = AdaptationSettings()
    for name, settings, adaptation in (
            ("adaptive + trim", base, adapt), ("feed-forward (--no-adapt)", base, None),
            ("  no lead", replace(base, lead_time=0.0, fall_lead_time=0.0), None),
            ("  no spline correction", replace(base, correction_gain=0.0), None)):
        r = run_closed_loop(params, RigPlant.from_file(rig_file, seed=0), profile, settings,
                            adaptation=adaptation, rated_torque=rated,
                            command_delay=args.delay)
        rows[name.strip()] = {
            "within_10pct": r.within_10pct, "worst_overshoot": r.worst_overshoot,
            "longest_overshoot_s": r.longest_overshoot_s,
            "steady_state_error": r.steady_state_error,
            "friction_scale": (float(r.friction_scale[-1]) if r.friction_scale is not None
                               else float("nan"))}  # (run_closed_loop always records it)
    if args.json:
        emit_json(rows)
        return 0
    sys.stdout.write(f"{'settings':26s} {'within ±10 %':>12s} {'worst over':>10s} "
                     f"{'longest >1.1':>12s} {'plateau err':>11s} {'mu scale':>8s}\n")
    for name, row in rows.items():
        sys.stdout.write(f"{name:26s} {100 * row['within_10pct']:11.1f}% "
                         f"{row['worst_overshoot']:10.3f} {row['longest_overshoot_s']:11.2f}s "
                         f"{100 * row['steady_state_error']:10.2f}% "
                         f"{row['friction_scale']:8.4f}\n")
    return 0
