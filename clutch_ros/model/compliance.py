"""Drivetrain compliance between the clutch and the measuring points, with a sticking clutch.

Thesis 3.1-3.2 (Test A): with soft drive shafts the torque builds up roughly in proportion to
ω_diff after a pressure step (a 3-4 s delay at the lowest ω_diff), the ω_diff the clutch
sees is not the one the wheel or motor sensors measure (hence the filtered Diff Omega), and a
clutch at ω_diff = 0 is locked: it transmits what the drivetrain imposes, not what a friction
law says. Parameters ``drivetrain.stiffness`` k [N m/rad] and ``drivetrain.damping``
c [N m s/rad] (:class:`~clutch_ros.model.params.DrivetrainParams`); k = 0 is the rigid
drivetrain (off): the estimator's outputs are then exactly those without this module.

Model (massless clutch hub between a torsional spring-damper and the friction interface).
Input: the measured slip speed ω_m [rad/s] (held over the step, as every model input). States:
the twist θ [rad] of the compliance and the clutch's own slip speed ω_c [rad/s] (0 exactly
while it sticks). The measured torque is what the compliance carries,
``T = k θ + c (ω_m − ω_c)``, and θ̇ = ω_m − ω_c. The pack model gives the kinetic capacity
``T_k = 2 R_e μ Σ S_n`` (μ at the filtered measured slip) and the static one ``T_s`` (μ at
ω = 0, never below T_k):

- stick (ω_c = 0): θ̇ = ω_m, ``T = k θ + c ω_m`` rises at k ω_m (the delay: T_s / (k ω_m));
  the clutch breaks away when |T| reaches T_s (the instant is found inside the step);
- slip (ω_c ≠ 0, direction s = sign ω_c): the hub is massless, so ``T = s T_k`` exactly and
  θ relaxes to s T_k / k with the time constant c / k; ω_c = ω_m − (s T_k − k θ) / c. When
  ω_c reaches 0 (or changes sign) within a step the clutch sticks again, the torque then
  ``k θ + c ω_m`` bounded by ±T_s. c = 0: θ follows s T_k / k at once, ω_c = ω_m.

Passive: the clutch dissipates ``T ω_c ≥ 0`` (slip: T has the sign of ω_c; stick: ω_c = 0),
the damper ``c θ̇² ≥ 0``, and the work fed at the measuring point ``∫ T ω_m dt`` equals the
change of the stored spring energy ``k θ² / 2`` (:func:`stored_energy`) plus both (exactly
for each stick or slip phase; the re-stick bound only removes energy). tests/model/
test_compliance.py checks the balance, the stick ramp and break-away against closed forms,
and that the compiled series (numba) equals the per-sample Python step bit for bit.

Coupling: the pack's μ (capacity) is evaluated at the filtered measured slip, as without
compliance (one way: the estimator has no measurement of ω_c); the simulated rig's truth plant
feeds its pack the clutch's own slip ω_c instead (:mod:`clutch_ros.rig.plant`).
"""

from __future__ import annotations

import logging
import math
import threading
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model import kernel
from clutch_ros.model.errors import InputError, KernelUnavailableError
from clutch_ros.model.friction import friction_coefficient, mu_scalar

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray
    from clutch_ros.model.params import ClutchParams

__all__ = ["Drivetrain", "capacities", "capacity_scalar", "drive_series", "stored_energy"]

_log = logging.getLogger(__name__)
_state: dict[str, Any] = {"series": None, "tried": False}
_LOCK = threading.Lock()


def _step(state: FloatArray, dt: float, omega: float, t_kin: float, t_static: float,
          k: float, c: float) -> float:
    """Advance ``state`` = [θ, ω_c] by ``dt`` [s]; return the transmitted torque [N m].

    ω_m = ``omega`` [rad/s] held; capacities ``t_kin`` ≤ ``t_static`` [N m]; k > 0, c ≥ 0.
    """
    theta: float = state[0]
    slip: float = state[1]
    rest = dt
    if slip == 0.0:
        torque = k * (theta + omega * dt) + c * omega
        if abs(torque) <= t_static:
            state[0] = theta + omega * dt
            return torque
        s = 1.0 if torque > 0.0 else -1.0
        t_star = 0.0  # the break-away instant inside the step
        if omega != 0.0:
            t_star = (s * t_static - c * omega - k * theta) / (k * omega)
            t_star = min(max(t_star, 0.0), dt)
        theta = theta + omega * t_star
        rest = dt - t_star
    else:
        s = 1.0 if slip > 0.0 else -1.0
    target = s * t_kin / k
    if c > 0.0:
        theta = target + (theta - target) * math.exp(-k * rest / c)
        slip = omega - (s * t_kin - k * theta) / c
    else:
        theta = target
        slip = omega
    if s * slip > 0.0:
        state[0] = theta
        state[1] = slip
        return s * t_kin
    torque = k * theta + c * omega  # sticks again
    if torque > t_static:
        torque = t_static
    elif torque < -t_static:
        torque = -t_static
    state[0] = (torque - c * omega) / k
    state[1] = 0.0
    return torque


def _series(dts: FloatArray, omega: FloatArray, t_kin: FloatArray, t_static: FloatArray,
            kc: FloatArray, state: FloatArray, torque: FloatArray, slip: FloatArray) -> None:
    """Run steps 1..n-1: ``torque[k]``, ``slip[k]`` (ω_c) after the step ending at k."""
    k = kc[0]
    c = kc[1]
    for j in range(dts.size):
        torque[j + 1] = _step(state, dts[j], omega[j + 1], t_kin[j + 1], t_static[j + 1], k, c)
        slip[j + 1] = state[1]


_STEP_PY = _step
_SERIES_PY = _series


def _compiled() -> Any:
    """Return the numba-compiled series loop, or None (the kernel's availability decides)."""
    if _state["tried"]:
        return _state["series"]
    with _LOCK:
        if not _state["tried"]:
            if kernel.available():  # sets NUMBA_CACHE_DIR; honours CLUTCH_KERNEL=0
                # numba is slow to import: loaded only when a compiled loop runs
                import numba

                jit = numba.njit(cache=True, nogil=True)
                g = globals()
                g["_step"] = jit(_STEP_PY)
                _state["series"] = jit(_SERIES_PY)
            _state["tried"] = True
    return _state["series"]


def drive_series(params: ClutchParams, dts: ArrayLike, omega: ArrayLike, t_kin: ArrayLike,
                 t_static: ArrayLike, state: FloatArray,
                 engine: str = "auto") -> tuple[FloatArray, FloatArray]:
    """Run the compliance over a series; return (torque [N m], clutch slip ω_c [rad/s]).

    ``omega``, ``t_kin``, ``t_static`` (n,): measured slip [rad/s] and the pack's kinetic
    and static capacities [N m] per sample; ``dts`` (n − 1,) [s]. ``state`` = [θ, ω_c] at
    sample 0 (updated in place to the last sample's). Element 0 of the results is NaN (the
    caller keeps sample 0's own outputs). ``engine`` as :func:`~clutch_ros.model.simulate
    .simulate`'s: the compiled loop and the Python one give the same bits.
    """
    kernel.check_engine(engine)
    dr = params.drivetrain
    om = np.ascontiguousarray(omega, dtype=float)
    n = om.size
    torque = np.full(n, math.nan)
    slip = np.full(n, math.nan)
    if n < 2:
        return torque, slip
    args = (np.ascontiguousarray(dts, dtype=float), om,
            np.ascontiguousarray(t_kin, dtype=float), np.ascontiguousarray(t_static, dtype=float),
            np.array([dr.stiffness, dr.damping]), state, torque, slip)
    loop = None if engine == "numpy" else _compiled()
    if loop is None and engine == "kernel":
        raise KernelUnavailableError(f"engine='kernel': {kernel.unavailable_reason()}")
    if loop is None:
        _SERIES_PY(*args)
        return torque, slip
    try:
        loop(*args)
    except kernel._state["numba_error"] as err:  # compilation failed: nothing ran
        if engine == "kernel":
            raise KernelUnavailableError(f"engine='kernel': compliance loop: {err}") from err
        _log.warning("compliance kernel: compilation failed (%s); Python loop", err)
        _state["series"] = None
        _SERIES_PY(*args)
    return torque, slip


def capacity_scalar(params: ClutchParams, mu: float, compression: float,
                    temperature: float) -> tuple[float, float]:
    """Return the pack's kinetic and static torque capacity [N m] at one sample.

    ``mu``: μ the pack used [-]; ``compression``: z_N [m]; ``temperature``: the lamella
    temperature used [°C]. Static: μ at ω = 0 (the film term vanishes there), at the pack's
    normal-force pressure; never below the kinetic one.
    """
    pk = params.pack
    zp = compression if compression > 0.0 else 0.0
    c2k = 2.0 * pk.effective_radius * pk.lamella_stiffness
    k_na = pk.lamella_stiffness / (pk.lamella_count * pk.piston_area)
    t_kin = c2k * mu * zp
    t_static = c2k * mu_scalar(params.friction, temperature, zp * k_na, 0.0) * zp
    return t_kin, max(t_static, t_kin)


def capacities(params: ClutchParams, mu: ArrayLike, compression: ArrayLike,
               temperature: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """:func:`capacity_scalar` over arrays (the same float operations per element)."""
    pk = params.pack
    zp = np.maximum(np.asarray(compression, dtype=float), 0.0)
    c2k = 2.0 * pk.effective_radius * pk.lamella_stiffness
    k_na = pk.lamella_stiffness / (pk.lamella_count * pk.piston_area)
    t_kin = c2k * np.asarray(mu, dtype=float) * zp
    mu_s = friction_coefficient(params, np.asarray(temperature, dtype=float), zp * k_na,
                                np.zeros_like(zp))
    return t_kin, np.maximum(c2k * mu_s * zp, t_kin)


def stored_energy(params: ClutchParams, twist: ArrayLike) -> Any:
    """Return the spring energy k θ² / 2 [J] of the twist θ [rad] (0 when off)."""
    energy = 0.5 * params.drivetrain.stiffness * np.square(np.asarray(twist, dtype=float))
    return energy if energy.ndim else float(energy)


class Drivetrain:
    """The compliance's state for the per-sample (numpy) path (module docstring).

    Args:
        params: :class:`~clutch_ros.model.params.ClutchParams` with
            ``drivetrain.stiffness`` > 0.

    """

    def __init__(self, params: ClutchParams) -> None:
        if not params.drivetrain.enabled:
            raise InputError("Drivetrain needs drivetrain.stiffness > 0 (0 = rigid: no state)")
        self.params = params
        self.state = np.zeros(2)

    @property
    def twist(self) -> float:
        """Twist θ of the compliance [rad]."""
        return float(self.state[0])

    @property
    def clutch_slip(self) -> float:
        """The clutch's own slip speed ω_c [rad/s] (0 while it sticks)."""
        return float(self.state[1])

    def reset(self, torque: float, slip_speed: float) -> None:
        """Settle at ``torque`` [N m] carried, the clutch slipping at ``slip_speed`` [rad/s]."""
        reset_state(self.params, self.state, torque, slip_speed)

    def step(self, dt: float, slip_speed: float, t_kin: float, t_static: float) -> float:
        """Advance by ``dt`` [s] with the measured slip [rad/s]; return the torque [N m]."""
        dr = self.params.drivetrain
        return _STEP_PY(self.state, dt, slip_speed, t_kin, t_static, dr.stiffness, dr.damping)


def reset_state(params: ClutchParams, state: FloatArray, torque: float,
                slip_speed: float) -> None:
    """Set ``state`` = [θ, ω_c] to carry ``torque`` [N m] with ω_c = ``slip_speed`` [rad/s]."""
    state[0] = torque / params.drivetrain.stiffness
    state[1] = slip_speed


def comply(params: ClutchParams, t: ArrayLike, omega: ArrayLike, torque: ArrayLike,
           pack_columns: tuple[ArrayLike, ArrayLike, ArrayLike],
           engine: str = "auto") -> FloatArray:
    """Return the torque through the compliance of a series simulated from equilibrium [N m].

    ``t`` [s], ``omega`` (measured slip [rad/s]), ``torque`` (the pack's [N m]) and
    ``pack_columns`` = (μ [-], z_N [m], temperature [°C]) of the pack's outputs, all (n,).
    Sample 0 keeps the pack's torque and starts the compliance carrying it (as the estimator
    does at an initialisation). Off (stiffness 0): ``torque`` unchanged.
    """
    out = np.array(torque, dtype=float)
    if not params.drivetrain.enabled or out.size == 0:
        return out
    om = np.asarray(omega, dtype=float)
    state = np.zeros(2)
    reset_state(params, state, float(out[0]), float(om[0]))
    t_kin, t_static = capacities(params, *pack_columns)
    series, _ = drive_series(params, np.diff(np.asarray(t, dtype=float)), om, t_kin, t_static,
                             state, engine)
    out[1:] = series[1:]
    return out
