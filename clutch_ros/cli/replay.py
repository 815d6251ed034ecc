"""``clutch replay BAG... --params P``: the estimator offline over recorded RigState streams.

Deterministic and faster than real time: each bag's RigState stream is read into arrays
(:func:`clutch_ros.bag.reader.read_rig_states`) and run through
:func:`clutch_ros.model.estimate_batch`, which gives results identical to the live estimator
node's per-sample ``update()`` (bad samples skipped the same way). Per bag it reports the
model's torque RMSE against the measured torque, the Eq. 1 reference RMSE with the same
friction law, the fraction of samples with accuracy in [0.9, 1.1] where the torque is above
5 % of its maximum, and the accuracy extremes. ``-o`` writes one ClutchEstimate per accepted
input sample (stamp = input stamp) on ``/clutch_estimate``; ``--report`` writes PNG plots.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from clutch_ros.errors import ClutchError

__all__ = ["add_parser", "run", "replay_bag"]


def add_parser(sub) -> None:
    """Register ``clutch replay``."""
    p = sub.add_parser("replay", help="run the estimator offline over bags",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("bags", nargs="+", metavar="BAG", help="bags holding RigState messages")
    p.add_argument("--params", required=True, help="parameter preset or YAML file")
    p.add_argument("--law", choices=("none", "ff_t", "ff_v", "coulomb"),
                   help="override spline.law of the parameter file (ff_t and ff_v take "
                        "Table 7's 10 rpm parameters)")
    p.add_argument("-o", "--output", metavar="OUT", help="write ClutchEstimate bag(s) here "
                   "(a directory of bags for several inputs)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--report", metavar="DIR", help="write PNG plots into DIR")
    p.add_argument("--json", action="store_true", help="print a JSON list, one object per bag")
    p.set_defaults(func=run)


def replay_bag(bag: Path, params) -> tuple[object, object]:
    """Return ``(rig arrays, EstimateBatch)`` for one bag (bad samples skipped)."""
    import numpy as np

    from clutch_ros.bag.reader import read_rig_states
    from clutch_ros.model import estimate_batch

    rig = read_rig_states(bag)
    if len(rig) == 0:
        raise ClutchError(f"{bag}: no RigState messages")
    measured = np.where(rig.has_measured_torque.astype(bool), rig.measured_torque, np.nan)
    batch = estimate_batch(params, rig.stamp, rig.actuating_pressure, rig.lamella_temperature,
                           rig.slip_speed, measured, on_reject="skip")
    return rig, batch


def run(args) -> int:
    """Replay every bag; print one summary line (or JSON object) per bag."""
    from clutch_ros.model import accuracy_summary
    from clutch_ros.params_file import load_params
    from clutch_ros.presets import preset_path

    params = load_params(preset_path(args.params))
    if args.law:  # ff_t/ff_v take Table 7's 10 rpm gain and time constant
        params = params.with_law(args.law)
    bags = [Path(b) for b in args.bags]
    outs = _outputs(bags, args.output)
    results = []
    for bag, out in zip(bags, outs):
        start = time.perf_counter()
        rig, batch = replay_bag(bag, params)
        ok = batch.accepted
        summary = accuracy_summary(batch.measured_torque[ok], batch.modelled_torque[ok],
                                   batch.reference_torque[ok])
        seconds = time.perf_counter() - start
        summary.update(bag=str(bag), law=params.spline.law, samples=int(len(rig)),
                       accepted=int(ok.sum()), skipped=int((~ok).sum()),
                       seconds=seconds, samples_per_s=len(rig) / max(seconds, 1e-9))
        if out is not None:
            _write_estimates(out, batch, args.storage)
            summary["output"] = str(out)
        if args.report:
            from clutch_ros.cli.replay_report import plot_replay

            summary["plots"] = [str(p) for p in plot_replay(bag, rig, batch, Path(args.report))]
        results.append(summary)
    if args.json:
        from clutch_ros.cli import emit_json

        emit_json(results)
    else:
        for r in results:
            sys.stdout.write(
                f"{r['bag']}: {r['samples']} samples ({r['skipped']} skipped), law {r['law']}: "
                f"RMSE {r['rmse_nm']:.2f} N m (reference {r['reference_rmse_nm']:.2f} N m), "
                f"within ±10 % {100 * r['within_10pct']:.1f} %, accuracy "
                f"{r['min_accuracy']:.3f}..{r['max_accuracy']:.3f}\n")
    return 0


def _outputs(bags, output):
    if output is None:
        return [None] * len(bags)
    out = Path(output)
    if len(bags) == 1:
        return [out]
    out.mkdir(parents=True, exist_ok=True)
    return [out / bag.name for bag in bags]


def _write_estimates(out: Path, batch, storage: str) -> None:
    from clutch_ros.bag.typestore import CLUTCH_ESTIMATE, clutch_estimate_msg
    from clutch_ros.bag.writer import BagWriter

    with BagWriter(out, storage=storage, delete_on_error=True) as writer:
        topic = writer.add_topic("/clutch_estimate", CLUTCH_ESTIMATE)
        for i in range(len(batch.stamp)):
            if not batch.accepted[i]:
                continue
            stamp_ns = int(round(float(batch.stamp[i]) * 1e9))
            msg = clutch_estimate_msg(
                stamp_ns,
                **{name: getattr(batch, name)[i] for name in _ESTIMATE_FIELDS},
                spline_law=batch.spline_law)
            writer.write(topic, stamp_ns, msg)


_ESTIMATE_FIELDS = (
    "modelled_torque", "reference_torque", "measured_torque", "torque_accuracy",
    "friction_coefficient", "lamella_normal_force", "spline_friction_force", "front_pressure",
    "rear_pressure", "pressure_difference", "slip_speed_filtered", "actuating_pressure",
    "lamella_temperature", "overshoot", "undershoot",
)
