"""Friction coefficient μ(T, p, ω, film) and the steady-state reference model (Eq. 1).

Units: lamella temperature T [°C], pressure p [Pa], slip speed ω = ω_diff [rad/s], torque
[N m]. Every function takes scalars or arrays (numpy broadcasting) and returns a float for
all-scalar input, else an array.

Friction coefficient (thesis 2.1.1 and 6.2, Hypothesis 2)::

    μ = max(μ_min, μ_ref · f_T · f_p · f_ω)
    f_T = 1 + temperature_slope · (T − temperature_ref)            linear decay with T
    f_p = 1 − pressure_loss_at_ref · max(p, 0) / pressure_ref      0 % at 0 Pa, 5 % at 40 bar
    g   = exp(−(ω / stribeck_speed)²)                              1 at standstill, → 0 sliding
    f_ω = 1 + (static_ratio − 1) · [g + (1 − g) · film_depth · (1 − φ)]

``φ`` ∈ [0, 1] is the oil-film state of :mod:`clutch_ros.model.film` (1 = intact film, the
default; it thins while the plates are pressed at low slip, Hypothesis 2). The bracket is a
convex combination of 1 and (1 − φ)·film_depth ≤ 1, so μ always lies between the kinetic and
the static value: a thinned film keeps μ near static_ratio·kinetic after the slip starts, until
the film recovers (the torque spike of PBD runs, thesis Fig. 46). With ``film_depth = 0`` (the
presets' default until fitted) μ is the classic Stribeck law.

Which pressure: the pack model evaluates μ at the pressure equivalent of its own mean normal
force, ``p = Σ S_n / (N A)`` (equal to the actuating pressure in steady state without spline
loss), so a change of the input pressure affects μ only as fast as the plates follow; at the
instant of a release μ does not jump while the pack is still closed. The steady-state
reference (Eq. 1) evaluates it at the actuating pressure, as the static MISO model does.

Torque sign: a clutch never produces energy, so the transmitted torque has the sign of
ω_diff = ω_input − ω_output. The sign is regularised by :func:`sign_factor`, the C¹ cubic
``s(x) = x (3 − x²) / 2`` for ``|x| < 1`` and ``sign(x)`` beyond, ``x = ω / sign_speed``
(default 0.01 rad/s): exactly ±1 for |ω| ≥ sign_speed, so the forward model and the
steady-state inverse (which works with magnitudes) agree exactly there; T·ω ≥ 0 always and the
torque is continuous through zero slip, where it is 0. :func:`torque_capacity` gives the
magnitude.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, overload

import numpy as np

from clutch_ros.model.arraytypes import FloatArray

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.params import ClutchParams, FrictionParams

__all__ = [
    "friction_coefficient",
    "slip_sign",
    "sign_factor",
    "sign_scalar",
    "torque_capacity",
    "reference_torque",
    "mu_scalar",
    "stribeck_weight",
]


def _out(value: FloatArray, *inputs: ArrayLike) -> float | FloatArray:
    # a float when every input is a scalar, else the array (the overloads below state it)
    if all(np.ndim(v) == 0 for v in inputs):
        return float(value)
    return value


@overload
def sign_factor(slip_speed: float, sign_speed: float) -> float: ...
@overload
def sign_factor(slip_speed: ArrayLike, sign_speed: float) -> FloatArray: ...
def sign_factor(slip_speed: ArrayLike, sign_speed: float) -> float | FloatArray:
    """Return the regularised sign s(ω / sign_speed) in [−1, 1] (module docstring)."""
    x = np.clip(np.asarray(slip_speed, dtype=float) / sign_speed, -1.0, 1.0)
    return _out(0.5 * x * (3.0 - x * x), slip_speed)


def sign_scalar(slip_speed: float, sign_speed: float) -> float:
    """Scalar fast path of :func:`sign_factor`."""
    x = slip_speed / sign_speed
    if x >= 1.0:
        return 1.0
    if x <= -1.0:
        return -1.0
    return 0.5 * x * (3.0 - x * x)


@overload
def stribeck_weight(fr: FrictionParams, slip_speed: float) -> float: ...
@overload
def stribeck_weight(fr: FrictionParams, slip_speed: ArrayLike) -> FloatArray: ...
def stribeck_weight(fr: FrictionParams, slip_speed: ArrayLike) -> float | FloatArray:
    """Return g = exp(−(ω / stribeck_speed)²) ∈ (0, 1] (1 at standstill)."""
    x = np.asarray(slip_speed, dtype=float) / fr.stribeck_speed
    return _out(np.exp(-(x * x)), slip_speed)


@overload
def friction_coefficient(params: ClutchParams, lamella_temperature: float, pressure: float,
                         slip_speed: float, film: float = 1.0) -> float: ...
@overload
def friction_coefficient(params: ClutchParams, lamella_temperature: ArrayLike,
                         pressure: ArrayLike, slip_speed: ArrayLike,
                         film: ArrayLike = 1.0) -> FloatArray: ...
def friction_coefficient(params: ClutchParams, lamella_temperature: ArrayLike,
                         pressure: ArrayLike, slip_speed: ArrayLike,
                         film: ArrayLike = 1.0) -> float | FloatArray:
    """Return μ [-] at lamella temperature [°C], pressure [Pa], slip [rad/s], film φ [-]."""
    fr = params.friction
    temp = np.asarray(lamella_temperature, dtype=float)
    press = np.asarray(pressure, dtype=float)
    omega = np.asarray(slip_speed, dtype=float)
    f_t = 1.0 + fr.temperature_slope * (temp - fr.temperature_ref)
    f_p = 1.0 - fr.pressure_loss_at_ref * np.maximum(press, 0.0) / fr.pressure_ref
    x = omega / fr.stribeck_speed
    g = np.exp(-(x * x))
    thin = fr.film_depth * (1.0 - np.asarray(film, dtype=float))
    f_w = 1.0 + (fr.static_ratio - 1.0) * (g + (1.0 - g) * thin)
    mu = np.maximum(fr.mu_ref * f_t * f_p * f_w, fr.mu_min)
    return _out(mu, lamella_temperature, pressure, slip_speed, film)


def mu_scalar(fr: FrictionParams, lamella_temperature: float, pressure: float, slip_speed: float,
              film: float = 1.0) -> float:
    """Scalar fast path of :func:`friction_coefficient` taking ``params.friction``."""
    f_t = 1.0 + fr.temperature_slope * (lamella_temperature - fr.temperature_ref)
    p = pressure if pressure > 0.0 else 0.0
    f_p = 1.0 - fr.pressure_loss_at_ref * p / fr.pressure_ref
    x = slip_speed / fr.stribeck_speed
    g = math.exp(-(x * x))
    f_w = 1.0 + (fr.static_ratio - 1.0) * (g + (1.0 - g) * fr.film_depth * (1.0 - film))
    mu: float = fr.mu_ref * f_t * f_p * f_w
    return mu if mu > fr.mu_min else fr.mu_min


@overload
def slip_sign(params: ClutchParams, slip_speed: float) -> float: ...
@overload
def slip_sign(params: ClutchParams, slip_speed: ArrayLike) -> FloatArray: ...
def slip_sign(params: ClutchParams, slip_speed: ArrayLike) -> float | FloatArray:
    """Return the regularised torque sign in [−1, 1] for ω [rad/s] (module docstring)."""
    return sign_factor(slip_speed, params.friction.sign_speed)


@overload
def torque_capacity(params: ClutchParams, actuating_pressure: float, lamella_temperature: float,
                    slip_speed: float, film: float = 1.0) -> float: ...
@overload
def torque_capacity(params: ClutchParams, actuating_pressure: ArrayLike,
                    lamella_temperature: ArrayLike, slip_speed: ArrayLike,
                    film: ArrayLike = 1.0) -> FloatArray: ...
def torque_capacity(params: ClutchParams, actuating_pressure: ArrayLike,
                    lamella_temperature: ArrayLike, slip_speed: ArrayLike,
                    film: ArrayLike = 1.0) -> float | FloatArray:
    """Return |Eq. 1| = 2 R_e μ F_N N with F_N = max(p, 0)·A [N m] (no sign, ≥ 0)."""
    pk = params.pack
    press = np.maximum(np.asarray(actuating_pressure, dtype=float), 0.0)
    mu = friction_coefficient(params, lamella_temperature, press, slip_speed, film)
    cap = 2.0 * pk.effective_radius * pk.lamella_count * pk.piston_area * mu * press
    return _out(cap, actuating_pressure, lamella_temperature, slip_speed, film)


@overload
def reference_torque(params: ClutchParams, actuating_pressure: float,
                     lamella_temperature: float, slip_speed: float) -> float: ...
@overload
def reference_torque(params: ClutchParams, actuating_pressure: ArrayLike,
                     lamella_temperature: ArrayLike, slip_speed: ArrayLike) -> FloatArray: ...
def reference_torque(params: ClutchParams, actuating_pressure: ArrayLike,
                     lamella_temperature: ArrayLike, slip_speed: ArrayLike) -> float | FloatArray:
    """Return the steady-state reference torque of Eq. 1 [N m], signed like ω_diff.

    ``T = 2 · R_e · μ · F_N · N · s(ω)`` with ``F_N = max(p, 0) · A``, μ from
    :func:`friction_coefficient` at the actuating pressure with an intact film (the static
    model has no film state) and ``s`` from :func:`sign_factor`.
    """
    cap = torque_capacity(params, actuating_pressure, lamella_temperature, slip_speed)
    sign = sign_factor(slip_speed, params.friction.sign_speed)
    return _out(cap * sign, actuating_pressure, lamella_temperature, slip_speed)
