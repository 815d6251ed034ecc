"""FlexiForce HT201 sensor array of the simulated rig: 4 front + 4 rear sensors (§4.1.1).

The thesis mounted four FlexiForce HT201 sensors on the frontmost (piston side, lamella N)
and four on the rearmost (lamella 1) separator disc, each in the recommended inverting op-amp
circuit ``V_out = V_ref·R_F/R_S`` (Eq. 5) on an MCP6004 with a 6 V supply. This module turns
the two lamella normal forces [N] into the eight output voltages [V] (front 1..4, rear 1..4).

Per sensor ``i`` on a lamella carrying the force ``F`` [N]:

* **Force split** — sensor ``i`` carries ``s_i·F`` with shares ``s_i`` that sum to 1 per
  lamella: ``(1 + δ_i)/Σ(1 + δ)`` with ``δ_i`` drawn uniformly in ``±share_imbalance``
  (pucks and glue never load four sensors evenly). With slip, ``slip_redistribution`` of a
  nominal share (0.25) moves from sensor 2 to sensor 4 of each lamella, scaled by
  ``tanh(|ω_diff|/redistribution_speed)`` — the thesis saw "R2 drop and R4 rise" when ω_diff
  was applied (§5.2), attributed to rig tensions tilting the pack.
* **Response** — nominal sensor: the concave inverse of the thesis' calibration polynomial
  through the origin (Eqs. 6–10), ``F = a·v² + b·v``, i.e.
  ``v_nom(F) = (−b + sqrt(b² + 4·a·F)) / (2a)``; the defaults ``a = 250 N/V²``,
  ``b = 500 N/V`` give 3.0 V at 3750 N (a quarter of the ≈15 kN at 40 bar), 3.6 V at 5 kN:
  "well below" 6 V as in §4.1.1. Sensor ``i`` outputs ``g_i·v_nom`` with a gain ``g_i`` drawn
  uniformly in ``1 ± gain_variation`` (datasheet acceptance: ±40 % sensor-to-sensor). Its own
  law is then exactly ``F = (a/g_i²)·v² + (b/g_i)·v`` (:meth:`FlexiForceArray.truth_polynomials`),
  so an identification fitting Eqs. 6–10 has a known answer.
* **Noise and clipping** — additive Gaussian noise (front sensors noisier, §5.1.1), then the
  op-amp output is clipped to ``[0, output_max]`` (single 6 V supply; MCP6004 swings to
  within tens of mV of its rails).

Hysteresis, drift and temperature sensitivity (Table 2) are neglected as in the thesis.
The gains and shares are drawn once at construction from the generator passed in; noise is
drawn from the same generator afterwards, so one seed reproduces everything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clutch_ros.rig.errors import RigConfigError, check_non_negative, check_positive

__all__ = ["FlexiForceArray", "FlexiForceParams", "SENSORS_PER_LAMELLA"]

#: Sensors per instrumented lamella (front and rear); the array holds twice as many.
SENSORS_PER_LAMELLA = 4


@dataclass(frozen=True)
class FlexiForceParams:
    """Parameters of :class:`FlexiForceArray` (SI units).

    Attributes:
        poly_a: nominal quadratic coefficient ``a`` of ``F = a·v² + b·v`` [N/V²] (default 250)
        poly_b: nominal linear coefficient ``b`` [N/V] (default 500)
        gain_variation: half-width of the uniform per-sensor voltage gain ``1 ± x`` [-]
            (default 0.4, the datasheet's ±40 %)
        share_imbalance: half-width of the uniform share perturbation ``δ`` [-] (default 0.15)
        slip_redistribution: fraction of a nominal share moved from sensor 2 to sensor 4 at
            full slip [-] (default 0.2; 0 disables)
        redistribution_speed: slip speed scale of that redistribution [rad/s] (default 0.5)
        noise_std_front: voltage noise of the front sensors, 1 sigma [V] (default 0.008)
        noise_std_rear: voltage noise of the rear sensors, 1 sigma [V] (default 0.004)
        output_max: op-amp output ceiling [V] (default 5.95, just below the 6 V supply)

    """

    poly_a: float = 250.0
    poly_b: float = 500.0
    gain_variation: float = 0.4
    share_imbalance: float = 0.15
    slip_redistribution: float = 0.2
    redistribution_speed: float = 0.5
    noise_std_front: float = 0.008
    noise_std_rear: float = 0.004
    output_max: float = 5.95

    def __post_init__(self) -> None:
        check_positive("flexiforce.poly_a", self.poly_a)
        check_positive("flexiforce.poly_b", self.poly_b)
        if not 0.0 <= self.gain_variation < 1.0:
            raise RigConfigError("flexiforce.gain_variation must be in [0, 1), "
                                 f"got {self.gain_variation!r}")
        if not 0.0 <= self.share_imbalance < 1.0:
            raise RigConfigError("flexiforce.share_imbalance must be in [0, 1), "
                                 f"got {self.share_imbalance!r}")
        if not 0.0 <= self.slip_redistribution <= 1.0:
            raise RigConfigError("flexiforce.slip_redistribution must be in [0, 1], "
                                 f"got {self.slip_redistribution!r}")
        check_positive("flexiforce.redistribution_speed", self.redistribution_speed)
        check_non_negative("flexiforce.noise_std_front", self.noise_std_front)
        check_non_negative("flexiforce.noise_std_rear", self.noise_std_rear)
        check_positive("flexiforce.output_max", self.output_max)

    def nominal_voltage(self, force):
        """Return the nominal (gain 1, noise-free, unclipped) voltage [V] for ``force`` [N]."""
        force = np.maximum(np.asarray(force, dtype=float), 0.0)
        a, b = self.poly_a, self.poly_b
        return (np.sqrt(b * b + 4.0 * a * force) - b) / (2.0 * a)


def _as_generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, int | np.integer):
        return np.random.default_rng(int(rng))
    raise RigConfigError(f"rng must be a numpy Generator or an integer seed, got {rng!r}")


class FlexiForceArray:
    """Eight FlexiForce voltages [V] (front 1..4, rear 1..4) from two lamella forces [N].

    Args:
        params: sensor parameters (defaults: :class:`FlexiForceParams`)
        rng: numpy ``Generator`` (or an integer seed) for the per-sensor gains and shares,
            then for the noise

    """

    def __init__(self, params: FlexiForceParams | None = None,
                 rng: np.random.Generator | int = 0) -> None:
        self.params = p = params or FlexiForceParams()
        self._rng = _as_generator(rng)
        n = 2 * SENSORS_PER_LAMELLA
        self._gains = self._rng.uniform(1.0 - p.gain_variation, 1.0 + p.gain_variation, n)
        delta = self._rng.uniform(-p.share_imbalance, p.share_imbalance, n) + 1.0
        delta = delta.reshape(2, SENSORS_PER_LAMELLA)
        self._shares = (delta / delta.sum(axis=1, keepdims=True)).reshape(n)
        self._noise_std = np.repeat([p.noise_std_front, p.noise_std_rear],
                                    SENSORS_PER_LAMELLA)
        # one share unit moved from sensor 2 to sensor 4 of each lamella
        move = np.zeros(SENSORS_PER_LAMELLA)
        move[1], move[3] = -1.0, 1.0
        self._move = np.tile(move * p.slip_redistribution / SENSORS_PER_LAMELLA, 2)

    @property
    def gains(self) -> np.ndarray:
        """Per-sensor voltage gains ``g_i`` (8,) [-], front 1..4 then rear 1..4."""
        return self._gains.copy()

    @property
    def shares(self) -> np.ndarray:
        """Per-sensor force shares at zero slip (8,) [-]; each lamella's four sum to 1."""
        return self._shares.copy()

    def truth_polynomials(self) -> np.ndarray:
        """Return each sensor's exact law ``F = a_i·v² + b_i·v`` as an (8, 2) array [a, b].

        Units: ``a_i`` [N/V²], ``b_i`` [N/V]. Valid below the clipping voltage.
        """
        g = self._gains
        return np.column_stack([self.params.poly_a / g**2, self.params.poly_b / g])

    def sensor_forces(self, front_force: float, rear_force: float,
                      slip_speed: float = 0.0) -> np.ndarray:
        """Return the force on each sensor (8,) [N] for the lamella forces [N] and slip [rad/s].

        Negative lamella forces (a lifted lamella) load the sensors with 0 N.
        """
        shares = self._shares
        if self.params.slip_redistribution > 0.0 and slip_speed:
            tilt = math.tanh(abs(float(slip_speed)) / self.params.redistribution_speed)
            shares = shares + self._move * tilt
        front, rear = max(float(front_force), 0.0), max(float(rear_force), 0.0)
        lamella = np.array((front,) * SENSORS_PER_LAMELLA + (rear,) * SENSORS_PER_LAMELLA)
        return shares * lamella

    def clean_voltages(self, sensor_forces) -> np.ndarray:
        """Return the noise-free, clipped voltages (8,) [V] for per-sensor forces (8,) [N]."""
        v = self._gains * self.params.nominal_voltage(sensor_forces)
        return np.clip(v, 0.0, self.params.output_max)

    def voltages(self, front_force: float, rear_force: float, slip_speed: float = 0.0,
                 noise: bool = True) -> np.ndarray:
        """Return the eight output voltages (8,) [V], front 1..4 then rear 1..4.

        Args:
            front_force: normal force on the front (piston-side, N-th) lamella [N]
            rear_force: normal force on the rear (1st) lamella [N]
            slip_speed: ω_diff [rad/s] (drives the share redistribution)
            noise: add the Gaussian voltage noise (draws from the generator)

        """
        forces = self.sensor_forces(front_force, rear_force, slip_speed)
        v = self._gains * self.params.nominal_voltage(forces)
        if noise:
            v = v + self._noise_std * self._rng.standard_normal(v.shape[0])
        # = np.clip(v, 0, output_max), same values; np.clip costs 3 us on 8 elements
        return np.minimum(np.maximum(v, 0.0), self.params.output_max)
