"""The truth plant of the simulated rig: pack model, pump, motor, thermal model, sensors.

A one-motor rig with a locked output shaft (thesis §4.4): the motor drives the input shaft at
the commanded slip speed ω_diff (through a first-order speed loop), the output shaft stands
still (0 rad/s), so ω_diff = input speed. Per step of ``dt`` [s]:

1. the pump (:class:`~clutch_ros.rig.pump.PumpModel`) turns the pressure request into the
   actuating pressure [Pa] and its current [A];
2. the motor speed follows the slip command with ``motor_time_constant``;
3. the lamella pack (:class:`clutch_ros.model.PackModel` on the *truth* parameters —
   default ``params/rig_truth.yaml``, coulomb spline law, deliberately different from the
   estimator's preset) gives torque [N m] and per-lamella normal forces [N] at the lamella
   temperature of the previous step;
4. the thermal model (:class:`~clutch_ros.rig.thermal.ThermalModel`) heats the pack with the
   slip power ``|T·ω_diff|`` [W];
5. the FlexiForce array (:class:`~clutch_ros.rig.flexiforce.FlexiForceArray`) turns the front
   (N-th) and rear (1st) lamella forces into eight voltages [V];
6. Gaussian sensor noise (:class:`NoiseParams`) is added to the measured signals.

Drivetrain compliance (the truth file's ``drivetrain.stiffness`` > 0, e.g. the ``rig_test_a``
preset; :mod:`clutch_ros.model.compliance`): the shafts between the clutch and the motor's
speed sensor and torque flange twist. The motor speed is then the measured slip ω_m, the
clutch slips at its own ω_c (0 while it sticks), which its pack, the heating and the
FlexiForce sensors see, and the flange measures the torque the compliance carries: after a
pressure step at low ω_m the torque builds up at k ω_m (the Test A delay, thesis 3.1). With
the stiffness 0 (every other preset) nothing of this runs.

:class:`RigSignals` holds every RigState signal in SI units plus the noise-free truth. One
seed (or numpy Generator) reproduces a run: it is split into independent streams for the
FlexiForce sensors (gains, shares, noise) and the other sensors' noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from clutch_ros.config.params_file import load_flat, load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import ClutchParams, PackModel
from clutch_ros.model.compliance import Drivetrain, capacity_scalar
from clutch_ros.rig.errors import RigConfigError, check_non_negative
from clutch_ros.rig.flexiforce import FlexiForceArray, FlexiForceParams
from clutch_ros.rig.pump import PumpModel, PumpParams
from clutch_ros.rig.thermal import ThermalModel, ThermalParams

__all__ = ["NoiseParams", "RigPlant", "RigPlantParams", "RigSignals", "load_truth_params"]

_NOISE_BLOCK = 1024  # noise samples drawn per generator call (speed; same values per seed)


@dataclass(frozen=True)
class NoiseParams:
    """Sensor noise, one standard deviation each (SI units; 0 disables).

    Attributes:
        torque: torque flange [N m] (default 1.5: ~0.1 % of a 1.5 kN m flange)
        pressure: actuating-pressure sensor [Pa] (default 2000 = 0.02 bar; the gauge
            transducer's output is floored at 0 Pa, as is the pump's)
        pump_pressure: the pump ECU's own outlet-pressure sensor [Pa] (default 5000)
        speed: input-shaft speed [rad/s] (default 0.005, ~0.05 rpm); the locked output
            shaft reads exactly 0
        temperature: thermocouples [°C] (default 0.1)
        current: pump current [A] (default 0.02)

    """

    torque: float = 1.5
    pressure: float = 2000.0
    pump_pressure: float = 5000.0
    speed: float = 0.005
    temperature: float = 0.1
    current: float = 0.02

    def __post_init__(self) -> None:
        for f in fields(self):
            check_non_negative(f"noise.{f.name}", getattr(self, f.name))


@dataclass(frozen=True)
class RigPlantParams:
    """Everything of the rig besides the pack model (SI units).

    Attributes:
        pump: pump dynamics and kick (:class:`PumpParams`)
        thermal: lamella and oil heat balance (:class:`ThermalParams`)
        flexiforce: FlexiForce sensors (:class:`FlexiForceParams`)
        noise: sensor noise (:class:`NoiseParams`)
        motor_time_constant: speed loop of the input motor [s] (default 0.05; 0 = ideal)
        axle_ratio: wheel speed = shaft speed / axle_ratio [-] (default 3.0: the input shaft
            turns with the front axle, the output with the rear one; 0 = no wheel speeds)

    Flat keys for a parameter file (next to the model keys): ``rig.pump.time_constant``,
    ``rig.noise.torque``, ``rig.motor_time_constant`` ... (see :meth:`from_flat`).
    """

    pump: PumpParams = field(default_factory=PumpParams)
    thermal: ThermalParams = field(default_factory=ThermalParams)
    flexiforce: FlexiForceParams = field(default_factory=FlexiForceParams)
    noise: NoiseParams = field(default_factory=NoiseParams)
    motor_time_constant: float = 0.05
    axle_ratio: float = 3.0

    def __post_init__(self) -> None:
        check_non_negative("rig.motor_time_constant", self.motor_time_constant)
        check_non_negative("rig.axle_ratio", self.axle_ratio)

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> RigPlantParams:
        """Build from ``rig.*`` dotted keys (other keys are ignored; unknown ``rig.*`` raise)."""
        groups = {"pump": PumpParams, "thermal": ThermalParams,
                  "flexiforce": FlexiForceParams, "noise": NoiseParams}
        values: dict[str, dict[str, Any]] = {name: {} for name in groups}
        top: dict[str, Any] = {}
        for key, value in flat.items():
            if not isinstance(key, str) or not key.startswith("rig."):
                continue
            parts = key.split(".")
            if len(parts) == 3 and parts[1] in groups:
                names = {f.name for f in fields(groups[parts[1]])}
                if parts[2] in names:
                    values[parts[1]][parts[2]] = value
                    continue
            elif len(parts) == 2 and parts[1] in ("motor_time_constant", "axle_ratio"):
                top[parts[1]] = value
                continue
            raise RigConfigError(f"unknown rig parameter {key!r}")
        return cls(**{name: groups[name](**kw) for name, kw in values.items()}, **top)


def load_truth_params(source: Any = None):
    """Return the truth ``ClutchParams``: from a ClutchParams, a path/preset name or the default.

    The default is the ``rig_truth`` preset (``params/rig_truth.yaml``).
    """
    if isinstance(source, ClutchParams):
        return source

    return load_params(preset_path(str(source) if source is not None else "rig_truth"))


@dataclass
class RigSignals:
    """One plant sample: RigState signals in SI units (measured) plus the truth behind them.

    Measured (what the rig sends): ``time`` [s], ``actuating_pressure`` [Pa],
    ``lamella_temperature``/``oil_temperature`` [°C], ``input_speed``/``output_speed``/
    ``slip_speed`` [rad/s] (slip = input − output), ``measured_torque`` [N m] with
    ``has_measured_torque``, ``torque_request`` [N m] (echo; NaN when the scenario has none),
    ``ff_voltages`` (8,) [V] front 1..4 then rear 1..4, ``wheel_speeds`` (4,) [rad/s] FL, FR,
    RL, RR (empty when disabled), ``pump_current`` [A], ``pump_pressure`` [Pa] (the pump ECU's
    sensor), ``requested_pressure`` [Pa] (the request the pump followed).

    Truth (noise-free, for tests): ``true_actuating_pressure`` [Pa], ``true_slip_speed``
    [rad/s], ``true_torque`` [N m], ``true_lamella_temperature``/``true_oil_temperature``
    [°C], ``normal_force`` (N,) [N] rear → front, ``spline_force`` (N,) [N],
    ``front_force``/``rear_force`` [N], ``front_pressure``/``rear_pressure``/
    ``pressure_difference`` [Pa], ``mu`` [-], ``pump_kick`` [Pa].
    """

    time: float
    actuating_pressure: float
    lamella_temperature: float
    oil_temperature: float
    input_speed: float
    output_speed: float
    slip_speed: float
    measured_torque: float
    has_measured_torque: bool
    torque_request: float
    ff_voltages: np.ndarray
    wheel_speeds: np.ndarray
    pump_current: float
    pump_pressure: float
    requested_pressure: float
    true_actuating_pressure: float
    true_slip_speed: float
    true_torque: float
    true_lamella_temperature: float
    true_oil_temperature: float
    normal_force: np.ndarray
    spline_force: np.ndarray
    front_force: float
    rear_force: float
    front_pressure: float
    rear_pressure: float
    pressure_difference: float
    mu: float
    pump_kick: float


def _split_rng(seed: Any) -> tuple[np.random.Generator, np.random.Generator]:
    if isinstance(seed, np.random.Generator):
        a, b = seed.spawn(2)
        return a, b
    if isinstance(seed, int | np.integer):
        sa, sb = np.random.SeedSequence(int(seed)).spawn(2)
        return np.random.default_rng(sa), np.random.default_rng(sb)
    raise RigConfigError(f"seed must be an integer or a numpy Generator, got {seed!r}")


class RigPlant:
    """The simulated rig's truth plant (see the module docstring).

    Args:
        truth: pack model parameters — a ``ClutchParams``, a parameter file path or preset
            name; default: the ``rig_truth`` preset
        params: pump, thermal, sensor, noise and motor parameters
        seed: integer seed or numpy Generator for the sensor variation and all noise

    """

    def __init__(self, truth: Any = None, params: RigPlantParams | None = None,
                 seed: Any = 0) -> None:

        self.truth = load_truth_params(truth)
        self.params = params or RigPlantParams()
        ff_rng, self._noise_rng = _split_rng(seed)
        self.pack = PackModel(self.truth)
        self.drive = Drivetrain(self.truth) if self.truth.drivetrain.enabled else None
        self.pump = PumpModel(self.params.pump)
        self.thermal = ThermalModel(self.params.thermal)
        self.flexiforce = FlexiForceArray(self.params.flexiforce, ff_rng)
        n = self.params.noise
        self._noise_scale = np.array([n.torque, n.pressure, n.pump_pressure, n.speed,
                                      n.temperature, n.temperature, n.current])
        self._noise: list[list[float]] = []  # rows of 7 (Python floats: cheap arithmetic)
        self._noise_index = 0
        self.reset()

    @classmethod
    def from_file(cls, path: Any = None, seed: Any = 0) -> RigPlant:
        """Build from one parameter file holding the truth model keys and ``rig.*`` keys.

        ``path`` is a file or preset name (default ``rig_truth``); ``rig.*`` keys absent from
        it keep their defaults (:meth:`RigPlantParams.from_flat`).
        """
        file = preset_path(str(path) if path is not None else "rig_truth")
        flat = load_flat(file)
        return cls(ClutchParams.from_flat(flat, source=str(file)),
                   RigPlantParams.from_flat(flat), seed)

    def reset(self, lamella_temperature: float | None = None,
              oil_temperature: float | None = None, pressure: float = 0.0) -> None:
        """Settle the plant: pump at ``pressure`` [Pa], no slip, temperatures [°C], time 0.

        Both temperatures default to ``thermal.initial_temperature`` (35 °C) independently:
        a Table 4 run at 60 °C warms the lamellas, not the oil sump.
        """
        self.time = 0.0
        self._steps = 0
        self.pump.reset(pressure)
        self.thermal.reset(lamella_temperature, oil_temperature)
        self.pack.reset(actuating_pressure=self.pump.pressure,
                        lamella_temperature=self.thermal.lamella_temperature)
        self._slip = 0.0
        if self.drive is not None:
            self.drive.reset(0.0, 0.0)  # stuck, nothing carried

    @property
    def slip_speed(self) -> float:
        """True slip speed ω_diff (= input shaft speed) [rad/s]."""
        return self._slip

    def _next_noise(self) -> list[float]:
        if self._noise_index >= len(self._noise):
            block = self._noise_rng.standard_normal((_NOISE_BLOCK, 7)) * self._noise_scale
            self._noise = block.tolist()  # same float64 values as the array's
            self._noise_index = 0
        row = self._noise[self._noise_index]
        self._noise_index += 1
        return row

    def step(self, dt: float, requested_pressure: float, slip_speed_command: float,
             torque_request: float = math.nan) -> RigSignals:
        """Advance by ``dt`` [s]; return the signals at the end of the step.

        Args:
            dt: step length [s]
            requested_pressure: pump pressure request [Pa] (NaN/negative → 0)
            slip_speed_command: commanded ω_diff = input shaft speed [rad/s]
            torque_request: torque request to echo [N m] (NaN: none)

        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise RigConfigError(f"plant step dt must be positive and finite, got {dt!r}")
        command = float(slip_speed_command)
        if not math.isfinite(command):
            raise RigConfigError(f"slip speed command must be finite, got {command!r}")
        prm = self.params
        pressure, current = self.pump.step(dt, requested_pressure)
        tau = prm.motor_time_constant
        self._slip = command if tau == 0.0 else (
            command + (self._slip - command) * math.exp(-dt / tau))
        slip = self._slip
        drive = self.drive
        if drive is None:
            sample = self.pack.step(dt, pressure, slip, self.thermal.lamella_temperature)
            torque = float(sample.torque)
        else:  # the clutch sees its own slip; the flange the torque the compliance carries
            sample = self.pack.step(dt, pressure, drive.clutch_slip,
                                    self.thermal.lamella_temperature)
            t_kin, t_static = capacity_scalar(self.truth, sample.mu, sample.compression,
                                              sample.lamella_temperature)
            torque = drive.step(dt, slip, t_kin, t_static)
            slip = drive.clutch_slip
        lamella, oil = self.thermal.step(dt, abs(torque * slip))
        normal = np.asarray(sample.normal_force, dtype=float)
        front, rear = float(normal[-1]), float(normal[0])
        ff = self.flexiforce.voltages(front, rear, slip)
        self._steps += 1
        self.time = self._steps * dt
        e = self._next_noise()
        input_speed = self._slip + e[3]
        ratio = prm.axle_ratio
        wheels = (np.array([input_speed, input_speed, 0.0, 0.0]) / ratio if ratio > 0.0
                  else np.zeros(0))
        return RigSignals(
            time=self.time, actuating_pressure=max(pressure + e[1], 0.0),
            lamella_temperature=lamella + e[4], oil_temperature=oil + e[5],
            input_speed=input_speed, output_speed=0.0, slip_speed=input_speed,
            measured_torque=torque + e[0], has_measured_torque=True,
            torque_request=float(torque_request), ff_voltages=ff, wheel_speeds=wheels,
            pump_current=max(current + e[6], 0.0), pump_pressure=max(pressure + e[2], 0.0),
            requested_pressure=float(requested_pressure),
            true_actuating_pressure=pressure, true_slip_speed=slip, true_torque=torque,
            true_lamella_temperature=lamella, true_oil_temperature=oil,
            normal_force=normal, spline_force=np.asarray(sample.spline_force, dtype=float),
            front_force=front, rear_force=rear,
            front_pressure=float(sample.front_pressure),
            rear_pressure=float(sample.rear_pressure),
            pressure_difference=float(sample.pressure_difference), mu=float(sample.mu),
            pump_kick=self.pump.kick,
        )
