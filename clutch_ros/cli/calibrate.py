"""``clutch calibrate BAG...``: FlexiForce calibration from RigState bags (thesis §5.5).

Fits both force-voltage calibrations of :mod:`clutch_ros.model.calibration` — "same force"
(Eqs. 6–9, one ``F = a v² + b v`` per sensor) and "same sensor" (Eq. 10, one law per disc) —
against the actuating force ``F_act = p · A`` (A from ``--params``), on quasi-static samples
(pressure steady for 0.5 s; ``--all-samples`` uses every sample, as the thesis did), and
reports both coefficient sets, the fit errors and how far the two methods' front/rear pressure
and P_diff estimates differ. ``-o FILE`` writes the comparison as YAML; ``--json`` prints it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yaml

from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.cli.dispatch import emit_json, standalone
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.errors import ClutchError
from clutch_ros.model.calibration import METHODS, compare_methods, quasi_static_mask
from clutch_ros.offline.flexiforce import flexiforce_voltages, read_calibration

__all__ = ["add_parser", "run", "main", "add_calibration_options", "calibration_from_args"]


def add_parser(sub) -> None:
    """Register ``clutch calibrate``."""
    p = sub.add_parser("calibrate", help="calibrate the FlexiForce sensors from bags",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("bags", nargs="+", metavar="BAG", help="bags holding RigState messages "
                   "with ff_voltages")
    p.add_argument("--params", default="flexiforce_8",
                   help="parameter preset or YAML file (piston area; default flexiforce_8)")
    p.add_argument("--all-samples", action="store_true",
                   help="fit on every sample, not only quasi-static ones")
    p.add_argument("-o", "--output", metavar="FILE", help="write the calibration as YAML")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    """Calibrate, print both methods and their comparison."""
    area = load_params(preset_path(args.params)).pack.piston_area
    volts, forces, masks = [], [], []
    for bag in args.bags:
        rig = read_rig_states(Path(bag))
        v = flexiforce_voltages(rig) if len(rig) else None
        if v is None:
            raise ClutchError(f"{bag}: no FlexiForce voltages (ff_voltages empty)")
        volts.append(v)
        forces.append(rig.actuating_pressure * area)
        masks.append(np.ones(len(rig), dtype=bool) if args.all_samples
                     else quasi_static_mask(rig.time, rig.actuating_pressure))
    if len({v.shape[1] for v in volts}) != 1:
        raise ClutchError("the bags have different numbers of FlexiForce sensors")
    comparison = compare_methods(np.concatenate(volts), np.concatenate(forces), area,
                                 np.concatenate(masks))
    doc = comparison.to_dict()
    doc["piston_area_m2"] = area
    doc["bags"] = [str(b) for b in args.bags]
    if args.output:
        try:
            Path(args.output).write_text(yaml.safe_dump(doc, sort_keys=False),
                                         encoding="utf-8")
        except OSError as err:
            raise ClutchError(f"{args.output}: cannot write ({err})") from err
    if args.json:

        emit_json(doc)
        return 0
    k = comparison.same_force.sensors_per_lamella
    names = [f"front {i + 1}" for i in range(k)] + [f"rear {i + 1}" for i in range(k)]
    lines = []
    for cal, title in ((comparison.same_force, "same force (Eqs. 6-9)"),
                       (comparison.same_sensor, "same sensor (Eq. 10)")):
        lines.append(f"{title}: F = a v^2 + b v on {cal.samples} samples, fit RMSE front "
                     f"{cal.rmse[0]:.0f} N, rear {cal.rmse[1]:.0f} N")
        for name, (a, b) in zip(names, cal.coefficients):
            lines.append(f"  {name:8s} a = {a:9.2f} N/V^2   b = {b:9.2f} N/V")
    lines.append(comparison.summary())
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def add_calibration_options(p, used_for: str) -> None:
    """Add ``--calibration METHOD`` and ``--calibration-file FILE`` to the parser ``p``.

    ``used_for`` completes the help texts (what the calibrated pressures feed).
    """
    p.add_argument("--calibration", choices=METHODS, default=METHODS[0],
                   help=f"FlexiForce calibration method for {used_for} (default: "
                        f"{METHODS[0]}, Eqs. 6-9)")
    p.add_argument("--calibration-file", metavar="FILE",
                   help="use this FlexiForce calibration (YAML of 'clutch calibrate -o') "
                        "instead of calibrating on the bags, e.g. for a single ramp that has "
                        "no pressure plateaus to calibrate on")


def calibration_from_args(args):
    """Return the calibration ``--calibration-file`` names, or None without one.

    The file's ``--calibration`` method is read (:func:`read_calibration`); without a file
    the commands calibrate on the bags themselves.
    """
    if not args.calibration_file:
        return None

    return read_calibration(args.calibration_file, args.calibration)



def main(argv=None) -> int:
    """``python -m clutch_ros.cli.calibrate BAG...`` (same as ``clutch calibrate``)."""
    return standalone(sys.modules[__name__], "calibrate", argv)


if __name__ == "__main__":
    sys.exit(main())
