"""The per-sample clutch torque estimator, shared by the ROS node, bag replay and tests.

:class:`ClutchEstimator` turns timestamped samples (actuating pressure [Pa], lamella
temperature [°C], slip speed ω_diff [rad/s], optional measured torque [N m]) into
:class:`Estimate` records whose fields mirror the ``ClutchEstimate`` message.

Per sample:

1. Validation, before any state changes: stamp, pressure and slip speed must be finite
   (:class:`NonFiniteSample`); the lamella temperature and the measured torque may be NaN
   (= not measured) but not ±inf. Without a lamella temperature the pack integrates its
   thermal state from the modelled slip power (``thermal.*``; it restarts at
   ``thermal.oil_temperature`` when the estimator initialises), so μ(T) follows heating; a
   measured temperature always wins. The stamp must be later than the last accepted one
   (:class:`OutOfOrderSample`, :class:`DuplicateSample`). A rejected sample leaves the
   estimator exactly as it was.
2. Time: dt = stamp − last accepted stamp. The first sample, and any sample after a gap
   longer than ``max_gap_s`` (default 1 s; e.g. a paused bag or a dropped link), initialise
   the pack to the static equilibrium at the sample's pressure with no spline force and the
   slip filter to the sample's slip (``reinitialised=True``): after a long gap the held-input
   assumption is meaningless, and equilibrium is the best guess.
3. The slip speed is low-passed (``slip.filter_time_constant``, the "filtered Diff Omega" the
   friction model uses), then the pack takes one exact ZOH step.
4. With a drivetrain compliance (``drivetrain.stiffness`` > 0, :mod:`~.compliance`) the
   modelled torque is what the compliance carries to the torque sensor: the pack gives the
   kinetic and static capacities, the compliance integrates the raw measured slip speed (a
   stuck clutch transmits what the drivetrain imposes, up to the static capacity). At an
   initialisation it starts carrying the pack's torque, the clutch slipping at the sample's
   slip speed. Off (the default), nothing changes.
5. Accuracy = measured / modelled (NaN without a measurement or when |modelled| <
   ``accuracy_min_torque``, default 1 N m); overshoot / undershoot: accuracy > 1.1 / < 0.9.

:func:`~clutch_ros.model.batch.estimate_batch` gives the same result as looping
:meth:`ClutchEstimator.update` over arrays (rejected samples raise, or with
``on_reject="skip"`` give NaN rows), running the pack through the compiled kernel or
:func:`~clutch_ros.model.simulate.simulate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.compliance import Drivetrain, capacity_scalar
from clutch_ros.model.errors import (
    DuplicateSample,
    InputError,
    NonFiniteSample,
    OutOfOrderSample,
)
from clutch_ros.model.pack import PackModel
from clutch_ros.model.slip import SlipFilter

if TYPE_CHECKING:
    from clutch_ros.model.params import ClutchParams

__all__ = ["ClutchEstimator", "Estimate"]


@dataclass(slots=True)
class Estimate:
    """One estimate (mirrors msg ``ClutchEstimate``; arrays rear → front, shape (N,)).

    Attributes:
        stamp: sample time [s]
        modelled_torque: pack torque, Eq. 27, signed like the slip [N m]
        reference_torque: steady-state torque, Eq. 1 with the same μ [N m]
        measured_torque: as given, NaN if absent [N m]
        torque_accuracy: measured / modelled, NaN if undefined
        friction_coefficient: μ [-]
        lamella_normal_force: S_n [N]
        spline_friction_force: F_fn [N]
        front_pressure, rear_pressure, pressure_difference: [Pa]
        slip_speed_filtered: filtered ω_diff used by the model [rad/s]
        spline_law: law name
        overshoot, undershoot: accuracy > 1.1, < 0.9
        actuating_pressure: input [Pa]; lamella_temperature: the temperature used, measured
        or the thermal state [°C];
        slip_speed: raw input [rad/s]; compression: z_N [m]
        spline_correction: pressure equivalent of the spline loss [Pa]
        reinitialised: the pack was (re)initialised to equilibrium at this sample
        clutch_slip_speed: the clutch's own slip speed ω_c behind the drivetrain compliance
            [rad/s] (0 while it sticks; NaN when the compliance is off)

    """

    stamp: float
    modelled_torque: float
    reference_torque: float
    measured_torque: float
    torque_accuracy: float
    friction_coefficient: float
    lamella_normal_force: np.ndarray
    spline_friction_force: np.ndarray
    front_pressure: float
    rear_pressure: float
    pressure_difference: float
    slip_speed_filtered: float
    spline_law: str
    overshoot: bool
    undershoot: bool
    actuating_pressure: float
    lamella_temperature: float
    slip_speed: float
    compression: float
    spline_correction: float
    reinitialised: bool
    clutch_slip_speed: float = math.nan


def _accuracy(measured: float, modelled: float, floor: float) -> float:
    if math.isnan(measured) or not abs(modelled) >= floor:
        return math.nan
    return measured / modelled


class ClutchEstimator:
    """Per-sample estimator (module docstring).

    Args:
        params: :class:`~clutch_ros.model.params.ClutchParams`.
        max_gap_s: a larger gap between stamps re-initialises to equilibrium [s].
        accuracy_min_torque: below this |modelled| the accuracy is NaN [N m].
        overshoot_limit, undershoot_limit: accuracy thresholds (1.1, 0.9).
        dt_resolution, transition: the pack's discretisation cache (:class:`PackModel`).

    """

    def __init__(self, params: ClutchParams, *, max_gap_s: float = 1.0,
                 accuracy_min_torque: float = 1.0,
                 overshoot_limit: float = 1.1, undershoot_limit: float = 0.9,
                 dt_resolution: float = 1e-5, transition: str = "auto"):
        if not (max_gap_s > 0.0 and accuracy_min_torque >= 0.0):
            raise InputError(f"max_gap_s must be > 0 and accuracy_min_torque >= 0, got "
                             f"{max_gap_s!r}, {accuracy_min_torque!r}")
        self.params = params
        self.max_gap_s = float(max_gap_s)
        self.accuracy_min_torque = float(accuracy_min_torque)
        self.overshoot_limit = float(overshoot_limit)
        self.undershoot_limit = float(undershoot_limit)
        self.pack = PackModel(params, dt_resolution=dt_resolution, transition=transition)
        self.slip_filter = SlipFilter(params.slip.filter_time_constant)
        self.drive = Drivetrain(params) if params.drivetrain.enabled else None
        self.last_stamp: float | None = None

    @property
    def spline_law(self) -> str:
        """Name of the spline-friction law in use."""
        return self.params.spline.law

    def reset(self) -> None:
        """Forget the history; the next sample initialises."""
        self.last_stamp = None
        self.slip_filter.reset()

    def set_params(self, params: ClutchParams) -> None:
        """Apply new parameters at runtime, keeping the pack state where its shape allows."""
        self.pack.set_params(params)
        self.slip_filter.time_constant = params.slip.filter_time_constant
        if not params.drivetrain.enabled:
            self.drive = None
        elif self.drive is None:  # switched on: starts at the next initialisation
            self.drive = Drivetrain(params)
            self.last_stamp = None
        else:  # the twist and the clutch slip are kept
            self.drive.params = params
        self.params = params

    def check(self, stamp_s: float, actuating_pressure: float, lamella_temperature: float,
              slip_speed: float, measured_torque: float = math.nan) -> None:
        """Raise the SampleRejected subclass ``update`` would raise; never changes state."""
        try:
            values = [float(v) for v in (stamp_s, actuating_pressure, lamella_temperature,
                                         slip_speed, measured_torque)]
        except (TypeError, ValueError) as err:
            raise NonFiniteSample(f"sample values must be numbers: {err}") from err
        if (not all(math.isfinite(v) for v in (values[0], values[1], values[3]))
                or math.isinf(values[2]) or math.isinf(values[4])):
            raise NonFiniteSample(
                f"non-finite sample: stamp={stamp_s!r}, actuating_pressure="
                f"{actuating_pressure!r}, lamella_temperature={lamella_temperature!r}, "
                f"slip_speed={slip_speed!r}, measured_torque={measured_torque!r}")
        if self.last_stamp is not None:
            if values[0] < self.last_stamp:
                raise OutOfOrderSample(f"stamp {values[0]!r} s is older than the last "
                                       f"accepted {self.last_stamp!r} s")
            if values[0] == self.last_stamp:
                raise DuplicateSample(f"stamp {values[0]!r} s repeats the last accepted one")

    def update(self, stamp_s: float, actuating_pressure: float, lamella_temperature: float,
               slip_speed: float, measured_torque: float = math.nan) -> Estimate:
        """Process one sample; return its estimate or raise SampleRejected (state untouched)."""
        self.check(stamp_s, actuating_pressure, lamella_temperature, slip_speed,
                   measured_torque)
        stamp, p = float(stamp_s), float(actuating_pressure)
        temp, omega = float(lamella_temperature), float(slip_speed)
        measured = float(measured_torque)
        last = self.last_stamp
        reinit = last is None or stamp - last > self.max_gap_s
        if reinit or last is None:  # (last None: reinit; spelt out for the type checker)
            self.slip_filter.reset(omega)
            omega_f = omega
            self.pack.reset(p, temp, omega_f)
            sample = self.pack.output(p, omega_f, temp)
        else:
            dt = stamp - last
            omega_f = self.slip_filter.update(dt, omega)
            sample = self.pack.step(dt, p, omega_f, temp)
        self.last_stamp = stamp
        torque, slip_c = sample.torque, math.nan
        drive = self.drive
        if drive is not None:
            if reinit or last is None:
                drive.reset(torque, omega)
            else:
                t_kin, t_static = capacity_scalar(self.params, sample.mu, sample.compression,
                                                  sample.lamella_temperature)
                torque = drive.step(stamp - last, omega, t_kin, t_static)
            slip_c = drive.clutch_slip
        acc = _accuracy(measured, torque, self.accuracy_min_torque)
        return Estimate(
            stamp, torque, sample.reference_torque, measured, acc, sample.mu,
            sample.normal_force, sample.spline_force, sample.front_pressure,
            sample.rear_pressure, sample.pressure_difference, omega_f, self.params.spline.law,
            acc > self.overshoot_limit, acc < self.undershoot_limit, p,
            sample.lamella_temperature, omega,
            sample.compression, self.pack.spline_correction(sample.spline_force), reinit,
            slip_c)
