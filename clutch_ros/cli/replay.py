"""``clutch replay BAG... --params P``: the estimator offline over recorded RigState streams.

Deterministic and faster than real time: each bag's RigState stream is read into arrays
(:func:`clutch_ros.bag.reader.read_rig_states`) and run through
:func:`clutch_ros.model.estimate_batch`, which gives results identical to the live estimator
node's per-sample ``update()`` (bad samples skipped the same way). Per bag it reports the
model's torque RMSE against the measured torque, the Eq. 1 reference RMSE with the same
friction law, the fraction of samples with accuracy in [0.9, 1.1] where the torque is above
5 % of its maximum, and the accuracy extremes. ``-o`` writes one ClutchEstimate per accepted
input sample (header = input header, as the node publishes it) on ``/clutch_estimate``;
``--report DIR`` writes PNG plots, among them the thesis's validation views (RMSE per
sequence, torque accuracy over time, P_diff vs the spline force, the residual
cross-correlation of Eq. 3; :mod:`clutch_ros.offline.replay_report`), listed per bag under
``plots`` in the JSON. The JSON also gives per bag the fraction of measured samples inside the
95 % band ``modelled_torque +- 1.96 modelled_torque_std`` (``coverage_95``, and separately
``coverage_95_transient`` / ``coverage_95_steady``; phases as
:func:`clutch_ros.offline.replay.uncertainty_summary` defines them), with the error model
``uncertainty.*`` of the parameter file (``clutch fit`` identifies it).
The report's measured P_diff comes from the bags' FlexiForce voltages,
calibrated on the replayed bags (``--calibration`` method) or taken from a calibration file
written by ``clutch calibrate -o`` (``--calibration-file``). The work is done by
:mod:`clutch_ros.offline.replay`.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from clutch_ros.bag.recover import recover_bag
from clutch_ros.bag.typestore import clutch_typestore
from clutch_ros.cli.calibrate import add_calibration_options, calibration_from_args
from clutch_ros.cli.dispatch import add_batch_options, check_batch_options, emit_json
from clutch_ros.cli.replay_adapt import AdaptiveRun, add_adapt_options, print_adaptation
from clutch_ros.config.params_file import load_flat, load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.errors import ClutchError
from clutch_ros.model.batch import warm_up
from clutch_ros.model.params import SPLINE_LAWS
from clutch_ros.model.uncertainty import ErrorModel, torque_std
from clutch_ros.offline.batch import run_jobs
from clutch_ros.offline.replay import ReplayJob, stamps_s, uncertainty_summary
from clutch_ros.offline.replay import replay_bag as replay
from clutch_ros.offline.replay_report import ReplayReport

__all__ = ["add_parser", "run", "replay_bag"]


def add_parser(sub) -> None:
    """Register ``clutch replay``."""
    p = sub.add_parser("replay", help="run the estimator offline over bags",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("bags", nargs="+", metavar="BAG", help="bags holding RigState messages")
    p.add_argument("--params", required=True, help="parameter preset or YAML file")
    p.add_argument("--law", choices=SPLINE_LAWS,
                   help="override spline.law of the parameter file (ff_t and ff_v take "
                        "Table 7's 10 rpm parameters; *_printed: Eqs. 29-30 as printed, not "
                        "passive, thesis reproduction only)")
    p.add_argument("-o", "--output", metavar="OUT", help="write ClutchEstimate bag(s) here "
                   "(a directory of bags for several inputs)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="storage plugin of the bags written (default: mcap)")
    p.add_argument("--report", metavar="DIR",
                   help="write PNG plots into DIR: per bag the replay and the validation views "
                        "(accuracy, P_diff vs spline force, residual cross-correlation), and the "
                        "RMSE per sequence")
    add_calibration_options(p, "the report's measured P_diff (with --report)")
    add_batch_options(p, "bags")
    add_adapt_options(p)
    p.add_argument("--topic", help="RigState topic to replay (default: the bag's only "
                   "RigState topic)")
    p.add_argument("--recover", action="store_true",
                   help="damaged MCAP bags (cut by a crash, a flipped bit): replay every "
                        "message up to each damage and report what was lost (messages, time "
                        "ranges) under 'recovery'")
    p.add_argument("--no-stream", action="store_true",
                   help="read each bag whole before estimating it (default: estimate in a "
                        "second thread while the bag is read, when a second core is free; "
                        "same results; never with --jobs/--cluster, whose bags use the cores)")
    p.add_argument("--json", action="store_true", help="print a JSON list, one object per bag")
    p.set_defaults(func=run)


def replay_bag(bag: Path, params) -> tuple[object, object]:
    """Return ``(rig arrays, EstimateBatch)`` for one bag (bad samples skipped)."""
    result = replay(bag, params)
    return result.rig, result.batch


def run(args) -> int:
    """Replay every bag; print one summary line (or JSON object) per bag."""
    params = load_params(preset_path(args.params))
    error_model = ErrorModel.from_flat(load_flat(preset_path(args.params)))
    if args.law:  # ff_t/ff_v take Table 7's 10 rpm gain and time constant
        params = params.with_law(args.law)
    bags = [Path(b) for b in args.bags]
    outs = _outputs(bags, args.output)
    for out in outs:  # fail before any work, not after the first bag
        if out is not None and out.exists():
            raise ClutchError(f"{out}: output exists already; bags are never overwritten")
    if args.calibration_file and not args.report:
        raise ClutchError("--calibration-file is used by the report's P_diff view: give "
                          "--report DIR too")
    report = None
    if args.report:
        report = ReplayReport(Path(args.report), params, params.spline.law,
                              calibration=args.calibration,
                              fixed_calibration=calibration_from_args(args))
    check_batch_options(args)
    adaptive = AdaptiveRun(args, params)
    if adaptive.enabled and (args.jobs != 1 or args.cluster):
        raise ClutchError("--adapt learns across the bags in order; it runs serially (drop "
                          "--jobs/--cluster)")
    if args.recover and args.cluster:
        raise ClutchError("--recover writes the recovered bags to a local scratch directory; "
                          "it cannot be combined with --cluster")
    serial = args.jobs == 1 and not args.cluster
    job = ReplayJob(params, storage=args.storage, keep_result=report is not None,
                    topic=args.topic, pipeline=None if serial and not args.no_stream else False,
                    error_model=error_model)
    results = []
    scratch = tempfile.TemporaryDirectory(prefix="clutch-recover-") if args.recover else None
    items, recoveries = [], []
    for index, (bag, out) in enumerate(zip(bags, outs)):
        recovery, spent = None, 0.0
        if scratch is not None:
            start = time.perf_counter()
            recovery = recover_bag(bag, Path(scratch.name) / f"{index}")
            spent = time.perf_counter() - start
            _say_recovery(recovery)
        items.append((Path(recovery["recovered_bag"]) if recovery else bag, out))
        recoveries.append((bag, recovery, spent))
    # serially, each bag's result is dropped before the next bag is read (bags may be
    # large); in parallel, the workers return summaries only (whole results with --report)
    done: Iterator[Any]
    if adaptive.enabled:
        done = (_adaptive_job(adaptive, item, args, error_model) for item in items)
    elif serial:
        done = (job(item) for item in items)
    else:
        if not args.cluster:  # load the compiled loop and the typestore once, before the
            warm_up(params)   # workers fork (each would build its own on its first bag)
            clutch_typestore()
        # largest bags first: a big bag started last would run alone at the end
        done = iter(run_jobs(job, items, jobs=args.jobs, cluster=args.cluster,
                             costs=[_bag_bytes(source) for source, _ in items]))
    for (bag, recovery, spent), (summary, result) in zip(recoveries, done):
        if recovery is not None:
            seconds = summary["seconds"] + spent
            summary.update(bag=str(bag), recovery=recovery, seconds=seconds,
                           samples_per_s=summary["samples"] / max(seconds, 1e-9))
        if report is not None:
            summary["plots"] = report.add(result)
        results.append(summary)
        del result  # the report keeps what it needs; the next bag may be large
    if scratch is not None:
        scratch.cleanup()
    if report is not None:
        report.finish(results)
    saved = adaptive.finish()
    if saved:
        for r in results:
            r["saved_params"] = saved
    if args.json:
        emit_json(results)
    else:
        for r in results:
            sys.stdout.write(
                f"{r['bag']}: {r['samples']} samples ({r['skipped']} skipped), law {r['law']}: "
                f"RMSE {r['rmse_nm']:.2f} N m (reference {r['reference_rmse_nm']:.2f} N m), "
                f"within ±10 % {100 * r['within_10pct']:.1f} %, accuracy "
                f"{r['min_accuracy']:.3f}..{r['max_accuracy']:.3f}\n")
            if adaptive.enabled:
                print_adaptation(r)
        if saved:
            sys.stdout.write(f"adapted parameters written to {saved}\n")
        if report is not None:
            plots = {p for r in results for p in r["plots"]}
            sys.stdout.write(f"report: {len(plots)} PNG files in {args.report}\n")
    return 0


def _adaptive_job(adaptive, item, args, error_model):
    """Replay one bag with the adaptive estimator (serial: it learns across the bags)."""
    source, out = item
    start = time.perf_counter()
    result, write = adaptive.replay(source, topic=args.topic)
    # modelled_torque_std of the adapted torque, as the node computes it
    b = result.batch
    result.torque_std = torque_std(error_model, stamps_s(result.rig), b.modelled_torque,
                                   b.slip_speed_filtered, b.measured_torque)
    summary = result.summary
    summary.update(uncertainty_summary(result.rig, result.batch, result.torque_std))
    seconds = time.perf_counter() - start
    summary.update(seconds=seconds, samples_per_s=summary["samples"] / max(seconds, 1e-9))
    if out is not None:
        summary["estimates_written"] = write(out, args.storage)
        summary["output"] = str(out)
    return summary, result


def _say_recovery(rep: dict) -> None:
    """One stderr line per skipped region of a recovered bag, and the missing counts."""
    for s in rep["skipped"]:
        span = "" if s["start_s"] is None else f", messages {s['start_s']:.3f}..{s['end_s']:.3f} s"
        count = "" if s["messages"] is None else f", {s['messages']} messages lost"
        count += f", {s['kept']} kept" if s.get("kept") else ""
        sys.stderr.write(f"clutch replay: {rep['bag']}: damage in {s['bytes']} bytes at offset "
                         f"{s['offset']} ({s['reason']}{count}{span})\n")
    if rep["missing"]:
        sys.stderr.write(f"clutch replay: {rep['bag']}: recovered {rep['recovered']}, missing "
                         f"{rep['missing']} of the declared counts\n")


def _bag_bytes(bag: Path) -> int:
    """Return the size of ``bag`` (a file, or a directory's files) [bytes]; 0 if unreadable."""
    try:
        if bag.is_dir():
            return sum(f.stat().st_size for f in bag.iterdir() if f.is_file())
        return bag.stat().st_size
    except OSError:  # the job itself reports a missing or unreadable bag
        return 0


def _outputs(bags, output):
    if output is None:
        return [None] * len(bags)
    out = Path(output)
    if len(bags) == 1:
        return [out]
    if out.exists() and not out.is_dir():
        raise ClutchError(f"{out}: not a directory (several bags write one output bag each)")
    names = [bag.name for bag in bags]
    if len(set(names)) != len(names):
        raise ClutchError("several input bags share a name; replay them into separate -o "
                          "directories")
    out.mkdir(parents=True, exist_ok=True)
    return [out / name for name in names]
