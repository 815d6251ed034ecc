"""Inverse model: the actuating pressure that gives a requested torque.

Steady state (Eq. 1 with μ's pressure dependence): solve ``C(p) = |T*|`` for p on
``[0, clutch.max_pressure]`` with ``C(p) = 2 R_e N A p μ(T, p, ω)`` the torque capacity
(:func:`~clutch_ros.model.friction.torque_capacity`), by ``scipy.optimize.brentq``. C is
continuous and strictly increasing on that interval (guaranteed by a parameter check, see
:class:`~clutch_ros.model.params.ClutchParams`), so the root is unique. The slip speed enters
through μ only (|ω|; the torque request is a magnitude, the direction is the slip's), so a
request at zero slip commands the static-friction capacity.

Agreement with the forward model: in steady state the pack's mean normal force equals the
actuating force (no spline loss), so μ at the pack's state equals μ at p, and the forward
torque is ``C(p) · s(ω)`` with the regularised sign exactly ±1 for ``|ω| ≥ sign_speed``
(0.01 rad/s by default; :mod:`clutch_ros.model.friction`): forward and inverse agree to
rounding there. Below it the forward torque fades to 0 at zero slip while the inverse keeps the
static capacity (a locked clutch transmits what it is asked to, up to that capacity). With the
oil film on, pass the pack's film state (``film``).

Requests: ``torque`` [N m] must be finite and ≥ 0 (controller requests are magnitudes);
0 N m commands 0 Pa. Unreachable requests (above C(max_pressure)): clamped to
``max_pressure`` by default (``limited`` / ``reason`` say so), or
:class:`~clutch_ros.model.errors.UnreachableTorqueError` with ``clamp=False``.

Dynamic correction: the controller adds ``spline_correction`` [Pa], the pressure equivalent
of the pack's current spline-friction loss (:meth:`PackModel.spline_correction`); the sum is
clamped to ``[0, max_pressure]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.errors import InputError, UnreachableTorqueError
from clutch_ros.model.friction import mu_scalar

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray
    from clutch_ros.model.params import ClutchParams

__all__ = ["PressureSolution", "solve_pressure", "pressure_for_torque",
           "pressure_for_torque_array", "capacity_scalar"]


@dataclass(frozen=True)
class PressureSolution:
    """Result of the inverse.

    Attributes:
        pressure: commanded actuating pressure, correction included, in [0, max] [Pa]
        steady_state_pressure: p with C(p) = |T*| (or max_pressure if unreachable) [Pa]
        correction: spline-friction correction requested [Pa]
        predicted_torque: C(steady_state_pressure), the steady-state torque magnitude [N m]
        limited: True if clamped (unreachable request or correction hit a bound)
        reason: empty, or why the result is limited

    """

    pressure: float
    steady_state_pressure: float
    correction: float
    predicted_torque: float
    limited: bool
    reason: str


def capacity_scalar(params: ClutchParams, pressure: float, lamella_temperature: float,
                    slip_speed: float, film: float = 1.0) -> float:
    """Torque capacity C(p) = 2 R_e N A p μ [N m] for scalars (fast path of the inverse)."""
    pk = params.pack
    p = pressure if pressure > 0.0 else 0.0
    mu = mu_scalar(params.friction, lamella_temperature, p, slip_speed, film)
    return 2.0 * pk.effective_radius * pk.lamella_count * pk.piston_area * mu * p


def _closed_form(params: ClutchParams, torque: float, lamella_temperature: float,
                 slip_speed: float, film: float, cap_max: float) -> float | None:
    """Return the root of ``C(p) = torque`` on ``[0, max_pressure]`` in closed form, or None.

    Where μ stays above its floor ``mu_min`` over the whole interval, μ is linear in p
    (``μ = m0 + m1 p``, the pressure loss) and ``C(p) = K p (m0 + m1 p)`` a quadratic: its
    root, in the cancellation-free form, polished by one Newton step on
    :func:`capacity_scalar` itself, equals brentq's to rounding at a fraction of the cost
    (the controller inverts two to four times per tick). None (floor reached, no root of the
    quadratic in the interval): the caller brackets with brentq.
    """
    pk, fr = params.pack, params.friction
    p_max = pk.max_pressure
    k = 2.0 * pk.effective_radius * pk.lamella_count * pk.piston_area
    m0 = mu_scalar(fr, lamella_temperature, 0.0, slip_speed, film)
    m_max = cap_max / (k * p_max)  # μ at max_pressure
    if not (m0 > fr.mu_min and m_max > fr.mu_min):  # μ linear only above its floor
        return None
    c0, c1 = k * m0, k * (m_max - m0) / p_max  # C(p) = c0 p + c1 p^2
    disc = c0 * c0 + 4.0 * c1 * torque
    if disc < 0.0:
        return None
    p = 2.0 * torque / (c0 + math.sqrt(disc))
    slope = c0 + 2.0 * c1 * p
    if slope > 0.0:
        p -= (capacity_scalar(params, p, lamella_temperature, slip_speed, film) - torque) / slope
    return p if 0.0 <= p <= p_max else None


def solve_pressure(params: ClutchParams, torque: float, lamella_temperature: float,
                   slip_speed: float,
                   spline_correction: float = 0.0, *, clamp: bool = True,
                   film: float = 1.0) -> PressureSolution:
    """Solve the inverse (module docstring) and report how the result was obtained.

    ``film``: the pack's oil-film state φ (1 = intact; :attr:`PackSample.film`).
    """
    try:
        torque, lamella_temperature, slip_speed, spline_correction = (
            float(torque), float(lamella_temperature), float(slip_speed),
            float(spline_correction))
    except (TypeError, ValueError) as err:
        raise InputError(f"inverse needs numbers: {err}") from err
    values = (torque, lamella_temperature, slip_speed, spline_correction)
    if not all(math.isfinite(v) for v in values):
        raise InputError(f"inverse needs finite numbers, got torque={torque!r}, "
                         f"lamella_temperature={lamella_temperature!r}, "
                         f"slip_speed={slip_speed!r}, spline_correction={spline_correction!r}")
    if torque < 0.0:
        raise InputError(f"torque request must be >= 0 N m (a magnitude), got {torque!r}")
    p_max = params.pack.max_pressure
    if torque == 0.0:
        return PressureSolution(0.0, 0.0, spline_correction, 0.0, False, "")
    reason = ""
    cap_max = capacity_scalar(params, p_max, lamella_temperature, slip_speed, film)
    if torque > cap_max:
        if not clamp:
            raise UnreachableTorqueError(f"{torque:.1f} N m exceeds the {cap_max:.1f} N m the "
                                    f"clutch transmits at {p_max / 1e5:.1f} bar "
                                    f"(T={lamella_temperature:.1f} degC, slip "
                                    f"{slip_speed:.3f} rad/s)")
        p_ss = p_max
        reason = f"unreachable: {torque:.1f} N m > {cap_max:.1f} N m at max pressure"
    else:
        closed = _closed_form(params, torque, lamella_temperature, slip_speed, film, cap_max)
        if closed is not None:
            p_ss = closed
        else:
            # scipy.optimize takes ~0.7 s to import: loaded by the first inversion that needs
            # it, not by everything that imports this module (clutch replay's start-up)
            from scipy.optimize import brentq

            p_ss = brentq(lambda p: capacity_scalar(params, p, lamella_temperature, slip_speed,
                                                    film) - torque,
                          0.0, p_max, xtol=1e-9, rtol=4 * np.finfo(float).eps, maxiter=200)
    pressure = p_ss + spline_correction
    if pressure > p_max:
        pressure = p_max
        reason = reason or "correction clamped at max pressure"
    elif pressure < 0.0:
        pressure = 0.0
        reason = reason or "correction clamped at 0 Pa"
    predicted = capacity_scalar(params, p_ss, lamella_temperature, slip_speed, film)
    return PressureSolution(float(pressure), float(p_ss), float(spline_correction),
                            float(predicted), bool(reason), reason)


def pressure_for_torque(params: ClutchParams, torque: float, lamella_temperature: float,
                        slip_speed: float,
                        spline_correction: float = 0.0, *, clamp: bool = True) -> float:
    """Return the actuating pressure [Pa] for a torque request [N m] (module docstring)."""
    return solve_pressure(params, torque, lamella_temperature, slip_speed, spline_correction,
                          clamp=clamp).pressure


def pressure_for_torque_array(params: ClutchParams, torque: ArrayLike,
                              lamella_temperature: ArrayLike, slip_speed: ArrayLike,
                              spline_correction: ArrayLike = 0.0, *,
                              clamp: bool = True) -> FloatArray:
    """Vectorised :func:`pressure_for_torque` (inputs broadcast) [Pa]."""
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (
        torque, lamella_temperature, slip_speed, spline_correction)))
    out = np.empty(arrays[0].shape)
    flat = [a.ravel().tolist() for a in arrays]
    res = [pressure_for_torque(params, *vals, clamp=clamp) for vals in zip(*flat)]
    out.reshape(-1)[:] = res
    return out
