"""FlexiForce pressures of recorded runs: bags -> calibrated front/rear disc pressures.

The domain side of ``clutch fit``, ``clutch calibrate`` and ``clutch replay --report``: read
RigState bags into :class:`~clutch_ros.model.identification.FitRun` objects, calibrate the
FlexiForce sensors on the runs themselves (thesis §5.5, Eqs. 6-10, fitted against
F_act = p·A on quasi-static samples) or take a calibration file written by
``clutch calibrate -o``, and turn sensor voltages [V] into front/rear pressures [Pa].
See ARCHITECTURE.md (offline layer).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np

from clutch_ros.bag.rig_states import REPLAY_FIELDS, model_inputs, read_rig_states
from clutch_ros.config.params_file import load_yaml
from clutch_ros.errors import ClutchError
from clutch_ros.model.calibration import (
    METHODS,
    CalibrationError,
    SensorCalibration,
    compare_methods,
    quasi_static_mask,
)
from clutch_ros.model.fit_data import FitRun
from clutch_ros.offline.batch import run_jobs

__all__ = ["FIT_FIELDS", "load_runs", "flexiforce_pressures", "flexiforce_voltages",
           "check_sensor_count", "read_calibration"]

#: The RigState fields a fit reads (the replay's and the FlexiForce voltages).
FIT_FIELDS = (*REPLAY_FIELDS, "ff_voltages")


def load_runs(bags, piston_area: float, *, pdiff: bool = True,
              calibration: str = "same_force", fixed=None, jobs: int = 1,
              cluster: str | None = None):
    """Read the bags into :class:`~clutch_ros.model.identification.FitRun` objects.

    The bags are read by ``jobs`` local processes or on the Dask scheduler ``cluster``
    (:func:`~clutch_ros.offline.batch.run_jobs`; same arrays as a serial read).

    Returns ``(runs, info)``; ``info`` holds the calibration (``calibration``: the fitted or
    given (``fixed``) :class:`~clutch_ros.model.calibration.SensorCalibration` or None,
    ``comparison``: both methods compared when fitted, ``calibration_error``: why there is
    none).
    """
    paths = [Path(bag) for bag in bags]
    read = partial(read_rig_states, fields=FIT_FIELDS)  # not the wheel speeds, currents ...
    arrays = list(zip(paths, run_jobs(read, paths, jobs=jobs, cluster=cluster)))
    for bag, rig in arrays:
        if len(rig) == 0:
            raise ClutchError(f"{bag}: no RigState messages")
    pressures, info = flexiforce_pressures([rig for _, rig in arrays], piston_area,
                                           calibration=calibration, enabled=pdiff,
                                           fixed=fixed)
    runs = []
    for (bag, rig), discs in zip(arrays, pressures):
        measured = model_inputs(rig.columns)[4]
        front, rear = discs if discs is not None else (None, None)
        runs.append(FitRun(rig.time, rig.actuating_pressure, rig.lamella_temperature,
                           rig.slip_speed, measured, name=bag.name, front_pressure=front,
                           rear_pressure=rear))
    return runs, info


def flexiforce_pressures(rigs, piston_area: float, *, calibration: str = "same_force",
                         enabled: bool = True, fixed=None):
    """Front/rear lamella pressures [Pa] from the FlexiForce voltages of RigState arrays.

    The sensors are calibrated on the runs themselves (thesis §5.5: both methods fitted
    against F_act = p·A on the quasi-static samples of every run with voltages, ``calibration``
    selecting the one used), unless ``fixed`` gives a ``SensorCalibration`` to use as it is
    (then a run whose sensor count differs from it raises :class:`ClutchError`). Returns
    ``(pressures, info)``: per run ``(front, rear)`` arrays (n,) or None (no voltages, no
    calibration), and ``info`` as :func:`load_runs` describes.
    """
    info: dict = {"calibration": None, "comparison": None, "calibration_error": None}
    if not enabled:
        return [None] * len(rigs), info
    voltages = [flexiforce_voltages(rig) for rig in rigs]
    if all(v is None for v in voltages):
        info["calibration_error"] = "no FlexiForce voltages in the bags"
        return [None] * len(rigs), info
    widths = {v.shape[1] for v in voltages if v is not None}
    if fixed is not None:
        check_sensor_count(fixed, widths)
        info["calibration"] = fixed
        return [None if v is None else _disc_pressures(fixed, v, piston_area)
                for v in voltages], info
    try:
        if len(widths) != 1:
            raise CalibrationError(f"the bags have different sensor counts {widths}")
        vs, forces, masks = [], [], []
        for rig, v in zip(rigs, voltages):
            if v is None:
                continue
            vs.append(v)
            forces.append(rig.actuating_pressure * piston_area)
            masks.append(quasi_static_mask(rig.time, rig.actuating_pressure))
        comparison = compare_methods(np.concatenate(vs), np.concatenate(forces),
                                     piston_area, np.concatenate(masks))
        info["comparison"] = comparison
        info["calibration"] = getattr(comparison, calibration)
    except CalibrationError as err:
        info["calibration_error"] = (f"{err} (no calibration on these bags: calibrate on a run "
                                     "with pressure plateaus, 'clutch calibrate -o FILE', and "
                                     "pass --calibration-file FILE)")
        return [None] * len(rigs), info
    return [None if v is None else _disc_pressures(info["calibration"], v, piston_area)
            for v in voltages], info


def check_sensor_count(cal, widths, where: str = "") -> None:
    """Raise :class:`ClutchError` unless every voltage width in ``widths`` is ``cal``'s 2k.

    ``where`` prefixes the message (e.g. ``"<bag>: "``).
    """
    if set(widths) != {2 * cal.sensors_per_lamella}:
        raise ClutchError(f"{where}the calibration is for {2 * cal.sensors_per_lamella} "
                          f"FlexiForce sensors, the bags have {sorted(widths)}")


def _disc_pressures(cal, voltages, piston_area: float):
    est = cal.pressures(voltages, piston_area)
    return est.front, est.rear


def flexiforce_voltages(rig):
    """Return the (n, 2k) FlexiForce voltages of a RigStateArrays, or None when absent."""
    v = getattr(rig, "ff_voltages", None)
    if v is None or v.ndim != 2 or v.shape[1] < 2 or v.shape[1] % 2:
        return None
    lengths = rig.columns.get("ff_voltages.len")
    if lengths is not None and not (np.asarray(lengths) == v.shape[1]).mean() > 0.5:
        return None
    return v


def read_calibration(path, method: str = "same_force"):
    """Read one method's calibration from a YAML file written by ``clutch calibrate -o``.

    The file holds both methods (``same_force``, ``same_sensor``: the mappings of
    :meth:`~clutch_ros.model.calibration.SensorCalibration.to_dict`); ``method`` picks one.
    Returns a :class:`~clutch_ros.model.calibration.SensorCalibration`; a missing file, bad
    YAML, a missing method or bad coefficients raise :class:`ClutchError` naming the file.
    """
    path = Path(path)
    if method not in METHODS:
        raise ClutchError(f"unknown calibration method {method!r} (one of {', '.join(METHODS)})")
    doc = load_yaml(path, "calibration file")
    entry = doc.get(method) if isinstance(doc, dict) else None
    if not isinstance(entry, dict):
        raise ClutchError(f"{path}: no {method!r} calibration in it (write one with "
                          "'clutch calibrate BAG... -o FILE')")
    if entry.get("method", method) != method:
        raise ClutchError(f"{path}: the {method!r} entry says method "
                          f"{entry.get('method')!r}")
    try:
        return SensorCalibration.from_dict(entry)
    except (CalibrationError, KeyError, TypeError, ValueError) as err:
        raise ClutchError(f"{path}: bad {method!r} calibration ({err})") from err
