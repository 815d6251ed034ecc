"""``clutch fit BAG... --law LAW -o PARAMS``: grey-box identification from RigState bags.

Reads every bag's RigState stream (:func:`clutch_ros.bag.reader.read_rig_states`), fits the
friction law, the spline law's parameters and the pack damping to the measured torque (and to
P_diff where FlexiForce voltages are present) with
:func:`clutch_ros.model.identification.fit`, and writes a complete parameter file the nodes
accept: the ``--base`` parameters (default ``flexiforce_8``) with the fitted values. Prints
each fitted value with its standard error and the fit RMSE; ``--json`` prints values, stderr,
rmse and the solver figures as JSON on stdout.

P_diff: when the bags carry ``ff_voltages`` (front sensors then rear sensors), the FlexiForce
sensors are calibrated on the bags themselves (thesis §5.5; ``--calibration same_force``
(default) or ``same_sensor``, fitted against F_act = p·A on quasi-static samples) and the
front−rear pressure difference joins the objective with ``--pdiff-weight`` (``--no-pdiff``
leaves it out). A failed calibration is reported and the fit goes on with the torque alone.
``--calibration-file FILE`` uses a calibration written by ``clutch calibrate -o`` instead
(the ``--calibration`` method of it), for bags without quasi-static plateaus to calibrate on
(a single ramp); a sensor count that does not match the bags is an error.

Data that cannot identify the model (no measured torque, constant pressure, too short, a
parameter without effect or confounded with another) are refused with a one-line error and
exit code 2; ``--fix KEY`` keeps a parameter at its base value. When a bag shows a
pressure-before-delta onset (pressure held at standstill, then slip) the oil-film friction
(``friction.film_depth``, ``friction.film_recovery_time``) is fitted too.

Reproducible: the solver stops after ``--max-evaluations`` residual evaluations (an
evaluation budget, not a wall-time limit; ``--max-seconds`` adds one only when asked), and the
file's header carries no clock time, so the same bags and options write the same file on an
idle or a loaded machine. ``--fit-compliance`` identifies the drivetrain compliance
(``drivetrain.stiffness``, ``drivetrain.damping``) too; without it they keep the base values.

The torque uncertainty (``uncertainty.*``, :mod:`clutch_ros.model.uncertainty`) is identified
on the fit bags replayed as the estimator node runs the ``--band`` mode (default ``adapted``:
the node's online adaptation; :mod:`clutch_ros.offline.band`), and the file gets the
``adapt.enabled`` / ``adapt.spline_gain`` of that mode. ``--band-bags`` adds runs the error
model alone is identified on (beside the fit bags; the estimator's parameters are not fitted
on them), so that its fitting set can cover regimes (slip speeds, ramps) the parameter fit
does not need.

``--law auto`` fits every passive law and writes the one with the lowest mean RMSE ratio
model / Eq. 1 on the ``--validate`` bags (on the fit bags without them), printing the ratio
per law and per validation run; ``--validate`` with one law scores just that law.
"""

from __future__ import annotations

import sys
from pathlib import Path

from clutch_ros.cli.calibrate import add_calibration_options, calibration_from_args
from clutch_ros.cli.dispatch import add_batch_options, check_batch_options, emit_json, standalone
from clutch_ros.config.params_file import load_params, write_params
from clutch_ros.config.presets import preset_path
from clutch_ros.errors import ClutchError
from clutch_ros.model.calibration import METHODS
from clutch_ros.model.identification import SAMPLE_BUDGET, FitOptions, fit
from clutch_ros.model.params import SPLINE_LAWS
from clutch_ros.numeric_env import usable_cores
from clutch_ros.offline.band import BAND_MODES, band_extra, fit_band
from clutch_ros.offline.fit_auto import (
    AutoFitResult,
    compliance_start,
    film_start,
    fit_auto,
    free_keys,
    score_law,
)
from clutch_ros.offline.flexiforce import load_runs

__all__ = ["add_parser", "run", "main"]

#: every registered spline law (model/laws.py), read when the parser is built
LAWS = SPLINE_LAWS


def add_parser(sub) -> None:
    """Register ``clutch fit``."""
    p = sub.add_parser("fit", help="fit the model to recorded rig data (grey-box)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("bags", nargs="+", metavar="BAG", help="bags holding RigState messages")
    p.add_argument("--law", required=True, choices=(*LAWS, "auto"),
                   help="spline-friction law to fit; auto: fit every passive law (none, ff_t, "
                        "ff_v, coulomb), report each one's RMSE ratio against Eq. 1 on the "
                        "--validate bags (else the fit bags) and write the best")
    p.add_argument("--validate", nargs="+", default=[], metavar="BAG",
                   help="bags to score the fitted model(s) on (RMSE ratio model / Eq. 1)")
    p.add_argument("--base", default="flexiforce_8",
                   help="parameter preset or YAML file giving the unfitted parameters and the "
                        "start values (default: flexiforce_8)")
    p.add_argument("-o", "--output", required=True, metavar="PARAMS",
                   help="parameter YAML file to write")
    p.add_argument("--fix", action="append", default=[], metavar="KEY",
                   help="keep this parameter at its base value (repeatable), e.g. "
                        "friction.temperature_slope")
    add_calibration_options(p, "the P_diff residual")
    p.add_argument("--no-pdiff", action="store_true",
                   help="fit the torque only, even when FlexiForce voltages are present")
    p.add_argument("--pdiff-weight", type=float, default=None, metavar="W",
                   help="weight of the P_diff residual in torque units (default 0.1)")
    p.add_argument("--fit-rate", type=float, default=None, metavar="HZ",
                   help="decimated rate of the fit (default 100 Hz)")
    p.add_argument("--max-samples", type=int, default=None, metavar="N",
                   help="segment budget per residual evaluation; 0: every sample at the "
                        "fit rate (default per law: "
                        + ", ".join(f"{k} {v}" for k, v in SAMPLE_BUDGET.items()) + ")")
    p.add_argument("--max-seconds", type=float, default=0.0, metavar="S",
                   help="also stop the solver at its best point after about S seconds (default "
                        "0: no wall-time limit, the fit then depends on the data only); the "
                        "result is then flagged as not converged")
    p.add_argument("--max-evaluations", type=int, default=FitOptions.max_nfev, metavar="N",
                   help="evaluation budget: residual evaluations of the solver per law "
                        f"(default {FitOptions.max_nfev}); the same bags give the same file")
    p.add_argument("--fit-compliance", action="store_true",
                   help="fit the drivetrain compliance (drivetrain.stiffness [N m/rad], "
                        "drivetrain.damping [N m s/rad]) too, and the samples at standstill "
                        "(a stuck clutch; left out otherwise); default: fixed at --base")
    p.add_argument("--threads", type=int, default=0, metavar="N",
                   help="threads computing the finite-difference Jacobian's columns at once "
                        "(default 0: one per core this process may use; 1: one after the "
                        "other); the result is the same")
    p.add_argument("--band", choices=BAND_MODES, default=BAND_MODES[0],
                   help="the estimate modelled_torque_std is identified on, replayed as the "
                        "node runs it: adapted (the friction scale, the node's default), "
                        "adapted_gain (and the spline gain), fixed (no adaptation); the file "
                        "gets the adapt.enabled / adapt.spline_gain that run it")
    p.add_argument("--band-bags", nargs="+", default=[], metavar="BAG",
                   help="further bags the error model (uncertainty.*) is identified on, beside "
                        "the fit bags; the estimator's parameters are not fitted on them")
    add_batch_options(p, "bags' reads")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    """Fit, write the parameter file, print the figures."""
    if args.pdiff_weight is not None and not args.pdiff_weight >= 0.0:
        raise ClutchError(f"--pdiff-weight must be >= 0, got {args.pdiff_weight}")
    if not args.threads >= 0:
        raise ClutchError(f"--threads must be >= 0 (0: one per core), got {args.threads}")
    if args.fit_rate is not None and not args.fit_rate > 0.0:
        raise ClutchError(f"--fit-rate must be > 0 Hz, got {args.fit_rate}")
    if args.max_samples is not None and 0 < args.max_samples < 100 or \
            args.max_samples is not None and args.max_samples < 0:
        raise ClutchError(f"--max-samples must be 0 (every sample) or >= 100, got "
                          f"{args.max_samples}")
    base = load_params(preset_path(args.base))
    out = Path(args.output)
    if out.is_dir():
        raise ClutchError(f"{out}: is a directory, expected a parameter file name")
    check_batch_options(args)
    fixed = calibration_from_args(args)
    runs, info = load_runs(args.bags, base.pack.piston_area, pdiff=not args.no_pdiff,
                           calibration=args.calibration, fixed=fixed, jobs=args.jobs,
                           cluster=args.cluster)
    kwargs = {}
    if args.pdiff_weight is not None:
        kwargs["pdiff_weight"] = args.pdiff_weight
    if args.fit_rate is not None:
        kwargs["fit_rate_hz"] = args.fit_rate
    if args.max_samples is not None:
        kwargs["max_samples"] = args.max_samples
    if not args.max_seconds >= 0.0:
        raise ClutchError(f"--max-seconds must be >= 0, got {args.max_seconds}")
    kwargs["max_seconds"] = args.max_seconds or None
    if not args.max_evaluations >= 1:
        raise ClutchError(f"--max-evaluations must be >= 1, got {args.max_evaluations}")
    kwargs["max_nfev"] = args.max_evaluations
    if args.fit_compliance:  # a stuck clutch is what the compliance explains: fit it too
        kwargs["min_slip_speed"] = 0.0
    kwargs["workers"] = args.threads or usable_cores()
    options = FitOptions(**kwargs)
    validation = []
    if args.validate:
        validation, _ = load_runs(args.validate, base.pack.piston_area, pdiff=False)
    auto = None
    if args.law == "auto":
        auto = fit_auto(runs, validation, base, fixed=args.fix, options=options,
                        compliance=args.fit_compliance)
        result = auto.best.result
        assert result is not None  # the best law is chosen among those that fitted
    else:
        keys = free_keys(args.law, runs, args.fix, compliance=args.fit_compliance)
        result = fit(runs, args.law, base, fixed=args.fix, free=keys,
                     start={**film_start(base, keys), **compliance_start(base, keys)},
                     options=options)
        if validation:
            score = score_law(args.law, result, validation)
            auto = AutoFitResult([score], score, [r.name for r in validation])
    law = result.params.spline.law
    header = (f"clutch fit --law {args.law} ({law}) --base {args.base}\n"
              f"bags: {', '.join(str(b) for b in args.bags)}\n"
              f"fit RMSE {result.rmse:.3f} N m; fitted: "
              + ", ".join(f"{k} = {result.values[k]:.6g} +- {result.stderr[k]:.2g}"
                          for k in result.keys))
    band_bags = [*args.bags, *args.band_bags]
    error_model = fit_band(band_bags, result.params, args.band)  # modelled_torque_std
    header += f"\nuncertainty.*: the {args.band} estimate's error model (--band)"
    if args.band_bags:
        header += f", also fitted on {', '.join(str(b) for b in args.band_bags)}"
    write_params(result.params, out, header=header,
                 extra={**error_model.to_flat(), **band_extra(args.band)})
    cal = info["calibration"]
    if args.json:
        doc = result.to_dict()
        doc.update(output=str(out), bags=[str(b) for b in args.bags],
                   pdiff=cal is not None and not args.no_pdiff,
                   calibration=None if cal is None else cal.to_dict(),
                   calibration_file=args.calibration_file,
                   calibration_comparison=(None if info["comparison"] is None
                                           else _comparison_brief(info["comparison"])),
                   calibration_error=info["calibration_error"],
                   uncertainty=error_model.to_flat(), band=args.band,
                   band_bags=[str(b) for b in band_bags])
        if auto is not None:
            doc.update(auto=[s.to_dict() for s in auto.scores], best_law=auto.best.law,
                       validated_on=auto.validated_on)
        emit_json(doc)
    else:
        lines = [f"fitted law {law} on {len(runs)} bag(s) -> {out}"]
        if auto is not None:
            lines += auto.lines()
        if cal is not None:
            source = (f"from {args.calibration_file}" if fixed is not None
                      else info["comparison"].summary())
            lines.append(f"P_diff from FlexiForce voltages ({cal.method} calibration; "
                         f"{source})")
        elif not args.no_pdiff and info["calibration_error"]:
            lines.append(f"no P_diff: {info['calibration_error']}")
        lines += result.lines()
        for name, value in zip(result.run_names, result.run_rmse):
            lines.append(f"  {name}: RMSE {value:.3f} N m")
        if not result.converged:
            lines.append(f"warning: the solver stopped early ({result.message})")
        sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _comparison_brief(comparison) -> dict:
    doc = comparison.to_dict()

    return {k: v for k, v in doc.items() if k not in METHODS}


def main(argv=None) -> int:
    """``python -m clutch_ros.cli.fit BAG... --law LAW -o PARAMS`` (same as ``clutch fit``)."""
    return standalone(sys.modules[__name__], "fit", argv)


if __name__ == "__main__":
    sys.exit(main())
