"""Oil-film state φ (Hypothesis 2, thesis 3.3 and Fig. 46) and the estimator's thermal state.

Both are scalar first-order states the pack model advances once per step, with the step's
inputs held, by their exact exponential solutions (so :func:`~clutch_ros.model.simulate.simulate`
and a :meth:`~clutch_ros.model.pack.PackModel.step` loop agree to rounding).

Oil film (φ ∈ [0, 1], 1 = intact): at low slip the lubrication from the grooves stops, and the
pressed plates squeeze the film out; sliding restores it::

    dφ/dt = −r_thin φ + r_rec (1 − φ)
    r_thin = (p / pressure_ref) · g / film_thinning_time       p = Σ S_n / (N A) ≥ 0
    r_rec  = (1 − g) / film_recovery_time                       g = exp(−(ω / stribeck_speed)²)

With r = r_thin + r_rec and φ_∞ = r_rec / r: ``φ⁺ = φ_∞ + (φ − φ_∞) e^{−r dt}`` (φ unchanged
when r = 0: an open clutch at standstill keeps its film). μ rises with the thinned film by
``(static_ratio − 1) (1 − g) film_depth (1 − φ)`` (:mod:`clutch_ros.model.friction`), so a
pressure-before-delta run (40 bar at standstill, then slip) starts slipping with μ near the
static value and falls to the kinetic one as the film recovers (≈ film_recovery_time): the
spike. Delta-before-pressure runs slip while pressed, so their film never thins.
``friction.film_depth = 0`` switches the effect off (the presets' default until fitted).

Thermal state (lamella temperature T_l [°C]) for an estimator without a lamella temperature
sensor: one lumped heat capacity heated by the modelled slip power and cooled to the oil, the
lamella equation of the simulated rig's thermal model::

    C dT_l/dt = P − G (T_l − T_oil),     P = |T_model · ω| [W]

exact for P held over the step: ``T⁺ = T_∞ + (T − T_∞) e^{−G dt / C}``, ``T_∞ = T_oil + P/G``.
A measured temperature (finite input) always wins and resets the state to it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from clutch_ros.model.params import FrictionParams, ThermalParams

__all__ = ["film_step", "film_equilibrium", "thermal_step"]


def _rates(fr: FrictionParams, pressure: float, slip_speed: float) -> tuple[float, float]:
    x = slip_speed / fr.stribeck_speed
    g = math.exp(-(x * x))
    p = pressure if pressure > 0.0 else 0.0
    return (p / fr.pressure_ref) * g / fr.film_thinning_time, (1.0 - g) / fr.film_recovery_time


def film_step(fr: FrictionParams, film: float, dt: float, pressure: float,
              slip_speed: float) -> float:
    """Advance φ by ``dt`` [s] at normal-force pressure [Pa] and slip [rad/s] held (docstring)."""
    thin, rec = _rates(fr, pressure, slip_speed)
    rate = thin + rec
    if rate <= 0.0:
        return film
    target = rec / rate
    return target + (film - target) * math.exp(-rate * dt)


def film_equilibrium(fr: FrictionParams, film: float, pressure: float, slip_speed: float) -> float:
    """Return φ_∞ at constant inputs (``film`` itself when both rates are zero)."""
    thin, rec = _rates(fr, pressure, slip_speed)
    rate = thin + rec
    return film if rate <= 0.0 else rec / rate


def thermal_step(th: ThermalParams, temperature: float, dt: float, power: float) -> float:
    """Advance the lamella temperature [°C] by ``dt`` [s] with ``power`` [W] held."""
    g = th.conductance
    target = th.oil_temperature + power / g
    return target + (temperature - target) * math.exp(-dt * g / th.heat_capacity)
