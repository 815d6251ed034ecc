"""Thermal model of the simulated rig: lamella heating from slip power, cooling to the oil.

Two lumped heat capacities (temperatures in °C, powers in W):

* the **lamella pack** (friction lamellas and separator discs near the friction surfaces, where
  the thesis' thermocouples sit), heated by the slip power ``P = |T·ω_diff|`` [W] (all of it
  is dissipated in the pack: the output shaft is locked, so no power leaves mechanically) and
  cooled to the oil through a conductance ``G`` [W/K]::

      C_l · dT_l/dt = P − G·(T_l − T_oil)

* the **oil** (sump, housing and the rig's oil conditioning), heated by the pack and held
  towards ``ambient_temperature`` (the conditioning setpoint) through ``G_a`` [W/K]::

      C_o · dT_oil/dt = G·(T_l − T_oil) − G_a·(T_oil − T_amb)

Each step integrates the lamella equation exactly for the oil temperature held over the step,
then the oil equation exactly for the new lamella temperature held (operator splitting; the
splitting error is O(dt/τ) with τ of seconds, i.e. ≈1e-4 at 1 kHz). With
``oil_heat_capacity = inf`` the oil is a fixed-temperature sink and the lamella temperature is
the exact first-order response with steady state ``T_oil + P/G`` and time constant ``C_l/G``.

Defaults and why: ``C_l = 1500 J/K`` (≈3 kg of steel and friction material at ≈500 J/(kg K));
``G = 60 W/K`` (oil-flow cooling with a locked output shaft, which the thesis notes circulates
oil poorly), giving ``τ_l = 25 s``. At 40 bar / 50 rpm (≈1.4 kN m·5.2 rad/s ≈ 7.5 kW) the pack
gains ≈70 K in 20 s and would settle ≈125 K above the oil; at 10 rpm a 10 s run gains ≈10 K —
the magnitudes of the thesis (35 °C start, up to ~150 °C). ``C_o = 2e4 J/K`` (≈5 l of oil plus
housing), ``G_a = 40 W/K`` to a 35 °C conditioning setpoint: the oil warms slowly (minutes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clutch_ros.rig.errors import RigConfigError, check_non_negative, check_positive

__all__ = ["ThermalModel", "ThermalParams"]


@dataclass(frozen=True)
class ThermalParams:
    """Parameters of :class:`ThermalModel` (SI units, temperatures in °C).

    Attributes:
        lamella_heat_capacity: C_l of the lamella pack [J/K] (default 1500)
        lamella_to_oil_conductance: G, pack to oil [W/K] (default 60)
        oil_heat_capacity: C_o of oil and housing [J/K] (default 2e4; inf holds the oil at its
            initial temperature)
        oil_to_ambient_conductance: G_a, oil to the conditioning setpoint [W/K] (default 40)
        ambient_temperature: oil conditioning setpoint T_amb [°C] (default 35)
        initial_temperature: lamella and oil temperature after ``reset()`` [°C] (default 35,
            the thesis' start temperature)

    """

    lamella_heat_capacity: float = 1500.0
    lamella_to_oil_conductance: float = 60.0
    oil_heat_capacity: float = 2.0e4
    oil_to_ambient_conductance: float = 40.0
    ambient_temperature: float = 35.0
    initial_temperature: float = 35.0

    def __post_init__(self) -> None:
        check_positive("thermal.lamella_heat_capacity", self.lamella_heat_capacity)
        check_positive("thermal.lamella_to_oil_conductance", self.lamella_to_oil_conductance)
        check_positive("thermal.oil_heat_capacity", self.oil_heat_capacity, allow_inf=True)
        check_non_negative("thermal.oil_to_ambient_conductance",
                           self.oil_to_ambient_conductance)
        for name in ("ambient_temperature", "initial_temperature"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise RigConfigError(f"thermal.{name} must be a finite number [°C], "
                                     f"got {value!r}")

    @property
    def lamella_time_constant(self) -> float:
        """Lamella time constant ``C_l/G`` against a fixed oil temperature [s]."""
        return self.lamella_heat_capacity / self.lamella_to_oil_conductance

    def steady_lamella_temperature(self, power: float, oil_temperature: float) -> float:
        """Return the lamella steady state ``T_oil + P/G`` [°C] for ``power`` [W]."""
        return oil_temperature + power / self.lamella_to_oil_conductance


class ThermalModel:
    """Lamella and oil temperatures [°C] driven by the slip power [W].

    ``step(dt, slip_power)`` advances by ``dt`` [s] with the power held over the step and returns
    ``(lamella_temperature, oil_temperature)`` [°C].
    """

    def __init__(self, params: ThermalParams | None = None) -> None:
        self.params = params or ThermalParams()
        self._cache: tuple[float, float, float] | None = None
        self.reset()

    def reset(self, lamella_temperature: float | None = None,
              oil_temperature: float | None = None) -> None:
        """Set the temperatures [°C]; defaults: ``initial_temperature`` for both."""
        init = self.params.initial_temperature
        self._lamella = float(init if lamella_temperature is None else lamella_temperature)
        self._oil = float(init if oil_temperature is None else oil_temperature)
        if not (math.isfinite(self._lamella) and math.isfinite(self._oil)):
            raise RigConfigError("thermal reset temperatures must be finite [°C]")

    @property
    def lamella_temperature(self) -> float:
        """Lamella temperature after the last step [°C]."""
        return self._lamella

    @property
    def oil_temperature(self) -> float:
        """Oil temperature after the last step [°C]."""
        return self._oil

    def _factors(self, dt: float) -> tuple[float, float, float]:
        cache = self._cache
        if cache is not None and cache[0] == dt:
            return cache
        p = self.params
        lam = math.exp(-dt * p.lamella_to_oil_conductance / p.lamella_heat_capacity)
        g_oil = p.lamella_to_oil_conductance + p.oil_to_ambient_conductance
        oil = 1.0 if math.isinf(p.oil_heat_capacity) else math.exp(
            -dt * g_oil / p.oil_heat_capacity)
        self._cache = (dt, lam, oil)
        return self._cache

    def step(self, dt: float, slip_power: float) -> tuple[float, float]:
        """Advance by ``dt`` [s] with ``slip_power`` [W] dissipated in the pack.

        Returns:
            ``(lamella_temperature, oil_temperature)`` [°C] at the end of the step.

        Raises:
            RigConfigError: ``dt`` is not positive and finite, or the power is NaN/negative.

        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise RigConfigError(f"thermal step dt must be positive and finite, got {dt!r}")
        power = float(slip_power)
        if not (power >= 0.0 and math.isfinite(power)):
            raise RigConfigError(f"slip power must be finite and >= 0 [W], got {slip_power!r}")
        p = self.params
        _, lam, oil = self._factors(dt)
        g = p.lamella_to_oil_conductance
        # lamella: exact response towards T_oil + P/G with the oil held
        target = self._oil + power / g
        self._lamella = target + (self._lamella - target) * lam
        # oil: exact response towards the conductance-weighted mean of lamella and ambient
        if oil < 1.0:
            g_a = p.oil_to_ambient_conductance
            oil_target = (g * self._lamella + g_a * p.ambient_temperature) / (g + g_a)
            self._oil = oil_target + (self._oil - oil_target) * oil
        return self._lamella, self._oil
