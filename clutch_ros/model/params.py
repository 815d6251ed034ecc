"""Typed, validated model parameters (the README.md parameter keys, SI units, temperatures in °C).

The flat form is a mapping of dotted keys (``clutch.lamella_count``...), exactly as the ROS 2
parameter files and nodes use them; :class:`ClutchParams` is the nested, frozen form the model
uses. The key namespace ``clutch.`` maps to the attribute ``pack``; ``friction.``, ``spline.``,
``slip.``, ``thermal.`` and ``drivetrain.`` (the compliance of :mod:`~.compliance`, off by
default) map to attributes of the same name.

:data:`PARAMETER_SPECS` is the single table of every key: unit, description, range and default
(``None`` = required). The ROS nodes build their ParameterDescriptors from it. Keys outside the
namespaces are ignored by :meth:`ClutchParams.from_flat` (nodes keep their own keys in the
same file); unknown keys inside them (typos), missing required keys, wrong types, non-finite
and out-of-range values raise :class:`ParameterError` naming the key.

Unit of ``spline.gain`` per law (Table 7 conversion, see :data:`TABLE7`):

The gains below hold for the passive laws and for the printed forms (``ff_t_printed``,
``ff_v_printed``) alike.

- ``ff_t`` (Eq. 29): κ in N of spline force per lamella per N m of transmitted torque, i.e.
  1/m, taken from Table 7 as printed. With κ = 0.3786 1/m and 1230 N m the peak force is
  ≈ 470 N per lamella, ≈ 3 % of the 15 kN actuating force, so the front-to-rear loss of an
  8-pack is ≈ 25 % at the instant of a torque step and decays with τ: the order of the
  thesis's P_diff transients. (Reading κ as bar per N m gives hundreds of bar, as bar per
  kN m a loss of ~1 %, far below the 1-11 % torque hysteresis of Tables 5-6.)
- ``ff_v`` (Eq. 30): κ in N per (N m · m/s) = s/m². Table 7's κ = 2 only gives plausible
  forces with ż in mm/s (with ż in m/s the force would be below 1 N), so the SI gain is
  2 × 1000 = 2000 s/m²: a step to 40 bar moves the front lamella of an 8-pack ≈ 0.3 mm,
  its filtered speed peaks at ≈ 0.15 mm/s and the force at ≈ 370 N, the same order as ff_t.
- ``coulomb`` and ``none`` ignore ``spline.gain``; coulomb uses
  ``spline.friction_coefficient`` and ``spline.radius``.

Preset values (``params/*.yaml``; the thesis gives few numbers, so these are chosen to match
the ones it gives): piston area 3.75e-3 m² (40 bar → 15 kN); per-lamella stiffness
k = 10 × 4e7 N/m (Eq. 28 from an assumed 10-pack stiffness, 0.3 mm compression of an 8-pack at
15 kN); damping c = 0.1 k, because with equal k, c per lamella every mode relaxes with the
same slow rate k/c, so the torque step response is first order with time constant c/k = 0.1 s
(thesis 6.4.2 fits c to that time constant); R_e and μ_ref give 1230 N m (8 lamellas), 1410
N m (13) and 1425 N m (10) at 40 bar, 35 °C, 10 rpm, inside the 1000-1500 N m of the rig and
just enough for Test B's 1440 N m cap. ``rig_truth.yaml`` differs on purpose (μ +6 %,
temperature slope, damping, static peak, coulomb law with a ≈ 0.006, i.e. ≈ ±5 % torque per
ramp direction, the order of Tables 5-6).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Protocol

from clutch_ros.model.errors import ParameterError
from clutch_ros.model.laws import LawNames, law_info

__all__ = [
    "ParamSpec",
    "PARAMETER_SPECS",
    "NAMESPACES",
    "SPLINE_LAWS",
    "TABLE7",
    "Table7Entry",
    "PackParams",
    "FrictionParams",
    "SplineParams",
    "SlipParams",
    "ThermalParams",
    "DrivetrainParams",
    "ClutchParams",
    "PASSIVE_LAWS",
]

#: Key namespace -> attribute of :class:`ClutchParams`.
NAMESPACES = {"clutch": "pack", "friction": "friction", "spline": "spline", "slip": "slip",
              "thermal": "thermal", "drivetrain": "drivetrain"}
#: Valid values of ``spline.law``: every law of the registry (:mod:`~clutch_ros.model.laws`),
#: the passive laws, then Eqs. 29-30 exactly as printed (not passive; for reproducing the
#: thesis only, never a default). A live view: a law registered later is in it.
SPLINE_LAWS = LawNames()
#: The laws that never do positive work on a lamella (live view of the registry).
PASSIVE_LAWS = LawNames("passive")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: dotted key, unit, description, type, range and default.

    ``default`` is ``None`` for required keys. Ranges are inclusive unless ``min_exclusive``.
    ``kind`` is ``"int"``, ``"float"`` or ``"str"``; strings list their ``choices``.
    """

    key: str
    unit: str
    description: str
    kind: str = "float"
    minimum: float | int | None = None
    maximum: float | int | None = None
    default: Any = None
    min_exclusive: bool = False
    choices: Sequence[str] = ()  # spline.law: a live view of the law registry

    def check(self, value: Any) -> Any:
        """Return ``value`` converted to this key's type; raise ParameterError if invalid."""
        if self.kind == "str":
            if not isinstance(value, str):
                raise ParameterError(self.key, f"expected a string, got {value!r}")
            if self.choices and value not in self.choices:
                raise ParameterError(self.key, f"{value!r} is not one of {', '.join(self.choices)}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(self.key, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ParameterError(self.key, f"must be finite, got {value!r}")
        if self.kind == "int":
            if float(value) != int(value):
                raise ParameterError(self.key, f"expected an integer, got {value!r}")
            value = int(value)
        else:
            value = float(value)
        low, high = self.minimum, self.maximum
        if low is not None and (value < low or (self.min_exclusive and value == low)):
            relation = ">" if self.min_exclusive else ">="
            raise ParameterError(self.key, f"must be {relation} {low}, got {value!r}")
        if high is not None and value > high:
            raise ParameterError(self.key, f"must be <= {high}, got {value!r}")
        return value


def _spec(key: str, unit: str, description: str, kind: str = "float",
          minimum: float | None = None, maximum: float | None = None, default: Any = None,
          min_exclusive: bool = False,
          choices: Sequence[str] = ()) -> tuple[str, ParamSpec]:
    choices = choices if isinstance(choices, LawNames) else tuple(choices)  # live: the laws
    return key, ParamSpec(key, unit, description, kind, minimum, maximum, default,
                          min_exclusive, choices)


#: Every model key (the README.md parameter contract plus model extras with defaults).
PARAMETER_SPECS: dict[str, ParamSpec] = dict([
    _spec("clutch.lamella_count", "", "number of lamellas N (2 friction surfaces each)",
          "int", 1, 100),
    _spec("clutch.effective_radius", "m", "effective friction radius R_e = (R_i + R_o)/2",
          minimum=0.0, maximum=1.0, min_exclusive=True),
    _spec("clutch.piston_area", "m^2", "actuating piston area A (F_act = p A)",
          minimum=0.0, maximum=1.0, min_exclusive=True),
    _spec("clutch.lamella_mass", "kg", "axially moving mass per lamella m",
          minimum=0.0, maximum=100.0, min_exclusive=True),
    _spec("clutch.lamella_stiffness", "N/m", "axial spring constant per lamella k "
          "(Eq. 28: 10 x the 10-pack stiffness)", minimum=0.0, maximum=1e12, min_exclusive=True),
    _spec("clutch.lamella_damping", "N s/m", "axial damping per lamella c; the torque "
          "time constant is c/k", minimum=0.0, maximum=1e12),
    _spec("clutch.max_pressure", "Pa", "highest actuating pressure the inverse may command",
          minimum=0.0, maximum=1e8, default=50e5, min_exclusive=True),
    _spec("friction.mu_ref", "", "kinetic friction coefficient at temperature_ref and 0 Pa",
          minimum=0.0, maximum=1.0, min_exclusive=True),
    _spec("friction.temperature_ref", "degC", "lamella temperature where mu = mu_ref",
          minimum=-60.0, maximum=400.0),
    _spec("friction.temperature_slope", "1/degC", "relative change of mu per degC "
          "(negative: mu decays linearly with temperature)", minimum=-0.05, maximum=0.05),
    _spec("friction.pressure_loss_at_ref", "", "fraction of mu lost at pressure_ref "
          "(linear from 0 at 0 Pa; thesis 6.2: 0.05 at 40 bar)", minimum=-0.5, maximum=0.5),
    _spec("friction.pressure_ref", "Pa", "pressure where the loss equals pressure_loss_at_ref",
          minimum=0.0, maximum=1e8, min_exclusive=True),
    _spec("friction.static_ratio", "", "static / kinetic friction coefficient at zero slip",
          minimum=0.5, maximum=3.0),
    _spec("friction.stribeck_speed", "rad/s", "slip speed of the Stribeck transition "
          "(Gaussian width)", minimum=0.0, maximum=100.0, min_exclusive=True),
    _spec("friction.sign_speed", "rad/s", "slip speed above which the torque sign is exactly "
          "+-1 (C1 cubic inside); <= stribeck_speed / 5", minimum=0.0, maximum=20.0,
          default=0.01, min_exclusive=True),
    _spec("friction.mu_min", "", "positive floor of the friction coefficient",
          minimum=0.0, maximum=1.0, default=0.01, min_exclusive=True),
    _spec("friction.film_depth", "", "oil-film friction (Hypothesis 2): fraction of the static "
          "rise (static_ratio - 1) a fully thinned film keeps while sliding; 0 = off",
          minimum=0.0, maximum=1.0, default=0.0),
    _spec("friction.film_thinning_time", "s", "time constant of film thinning at standstill "
          "under pressure_ref", minimum=0.0, maximum=1e4, default=1.0, min_exclusive=True),
    _spec("friction.film_recovery_time", "s", "time constant of film recovery while sliding",
          minimum=0.0, maximum=1e4, default=0.2, min_exclusive=True),
    _spec("spline.law", "", "spline-friction law (ff_t_printed, ff_v_printed: Eqs. 29-30 as "
          "printed, not passive, thesis reproduction only)", "str", default=None,
          choices=SPLINE_LAWS),
    _spec("spline.gain", "law-specific", "kappa: ff_t 1/m (N per N m), ff_v s/m^2 "
          "(N per N m per m/s); unused by none and coulomb", minimum=0.0, maximum=1e9),
    _spec("spline.time_constant", "s", "tau of Eq. 29 / Eq. 30", minimum=0.0, maximum=1e4,
          min_exclusive=True),
    _spec("spline.friction_coefficient", "", "coulomb: spline friction coefficient mu_s",
          minimum=0.0, maximum=1.0, default=0.05),
    _spec("spline.radius", "m", "coulomb: pitch radius of the lamella spline r_s",
          minimum=0.0, maximum=1.0, default=0.05, min_exclusive=True),
    _spec("thermal.heat_capacity", "J/K", "estimator thermal state (used when no lamella "
          "temperature is measured): lamella pack heat capacity C", minimum=0.0, maximum=1e7,
          default=1500.0, min_exclusive=True),
    _spec("thermal.conductance", "W/K", "estimator thermal state: lamella-to-oil conductance G",
          minimum=0.0, maximum=1e6, default=60.0, min_exclusive=True),
    _spec("thermal.oil_temperature", "degC", "estimator thermal state: oil temperature the "
          "pack cools to, and its start temperature", minimum=-60.0, maximum=400.0,
          default=35.0),
    _spec("slip.filter_time_constant", "s", "first-order low pass of the slip speed "
          "('filtered Diff Omega'); 0 = unfiltered", minimum=0.0, maximum=100.0, default=0.02),
    _spec("drivetrain.stiffness", "N m/rad", "torsional stiffness between the clutch and the "
          "slip and torque measuring points (model/compliance.py); 0 = rigid, compliance off",
          minimum=0.0, maximum=1e8, default=0.0),
    _spec("drivetrain.damping", "N m s/rad", "torsional damping in parallel with "
          "drivetrain.stiffness (unused while the stiffness is 0)", minimum=0.0, maximum=1e6,
          default=0.0),
])


@dataclass(frozen=True)
class Table7Entry:
    """One column of thesis Table 7 with its SI gain (see the module docstring)."""

    law: str
    slip_rpm: int
    kappa_thesis: float
    time_constant: float  # [s]
    gain_si: float  # ff_t: 1/m; ff_v: s/m^2


#: Thesis Table 7: (law, slip speed in rpm) -> fitted parameters.
TABLE7: dict[tuple[str, int], Table7Entry] = {
    ("ff_t", 10): Table7Entry("ff_t", 10, 0.3786, 0.9434, 0.3786),
    ("ff_v", 10): Table7Entry("ff_v", 10, 2.0, 2.0, 2.0 * 1000.0),
    ("ff_t", 30): Table7Entry("ff_t", 30, 0.3705, 1.9384, 0.3705),
    ("ff_v", 30): Table7Entry("ff_v", 30, 2.0, 2.5, 2.0 * 1000.0),
}


class _Dataclass(Protocol):
    """Any dataclass instance (what ``dataclasses.fields`` takes)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]


def _validated(obj: _Dataclass, namespace: str) -> None:
    for f in fields(obj):
        spec = PARAMETER_SPECS[f"{namespace}.{f.name}"]
        object.__setattr__(obj, f.name, spec.check(getattr(obj, f.name)))


@dataclass(frozen=True)
class PackParams:
    """Lamella pack (keys ``clutch.*``): geometry, mass, stiffness, damping; SI units."""

    lamella_count: int
    effective_radius: float  # [m]
    piston_area: float  # [m^2]
    lamella_mass: float  # [kg]
    lamella_stiffness: float  # [N/m]
    lamella_damping: float  # [N s/m]
    max_pressure: float = 50e5  # [Pa]

    def __post_init__(self) -> None:
        _validated(self, "clutch")


@dataclass(frozen=True)
class FrictionParams:
    """Friction coefficient law (keys ``friction.*``), see :mod:`clutch_ros.model.friction`."""

    mu_ref: float
    temperature_ref: float  # [°C]
    temperature_slope: float  # [1/°C]
    pressure_loss_at_ref: float  # fraction
    pressure_ref: float  # [Pa]
    static_ratio: float
    stribeck_speed: float  # [rad/s]
    sign_speed: float = 0.01  # [rad/s]
    mu_min: float = 0.01
    film_depth: float = 0.0
    film_thinning_time: float = 1.0  # [s]
    film_recovery_time: float = 0.2  # [s]

    def __post_init__(self) -> None:
        _validated(self, "friction")


@dataclass(frozen=True)
class SplineParams:
    """Spline-friction law (keys ``spline.*``), see :mod:`clutch_ros.model.spline`."""

    law: str
    gain: float  # unit per law, see module docstring
    time_constant: float  # [s]
    friction_coefficient: float = 0.05
    radius: float = 0.05  # [m]

    def __post_init__(self) -> None:
        _validated(self, "spline")


@dataclass(frozen=True)
class SlipParams:
    """Slip-speed filtering (keys ``slip.*``)."""

    filter_time_constant: float = 0.02  # [s]

    def __post_init__(self) -> None:
        _validated(self, "slip")


@dataclass(frozen=True)
class ThermalParams:
    """Estimator thermal state (keys ``thermal.*``), see :mod:`clutch_ros.model.film`."""

    heat_capacity: float = 1500.0  # [J/K]
    conductance: float = 60.0  # [W/K]
    oil_temperature: float = 35.0  # [°C]

    def __post_init__(self) -> None:
        _validated(self, "thermal")


@dataclass(frozen=True)
class DrivetrainParams:
    """Drivetrain compliance (keys ``drivetrain.*``), see :mod:`clutch_ros.model.compliance`."""

    stiffness: float = 0.0  # [N m/rad]; 0: rigid (off)
    damping: float = 0.0  # [N m s/rad]

    def __post_init__(self) -> None:
        _validated(self, "drivetrain")

    @property
    def enabled(self) -> bool:
        """True when the compliance is on (stiffness > 0)."""
        return self.stiffness > 0.0


_GROUPS = {"pack": PackParams, "friction": FrictionParams, "spline": SplineParams,
           "slip": SlipParams, "thermal": ThermalParams, "drivetrain": DrivetrainParams}


@dataclass(frozen=True)
class ClutchParams:
    """The complete, validated model parameter set (frozen; use :meth:`replace` to change).

    Cross-key rules checked here: ``friction.sign_speed <= friction.stribeck_speed / 5`` (the
    sign regularisation must be much narrower than the Stribeck transition);
    ``friction.mu_min <= friction.mu_ref``; the transmitted torque must grow with pressure up
    to ``clutch.max_pressure`` (so the inverse is unique): with a pressure loss > 0,
    ``max_pressure < pressure_ref / (2 pressure_loss_at_ref)``.
    """

    pack: PackParams
    friction: FrictionParams
    spline: SplineParams
    slip: SlipParams = field(default_factory=SlipParams)
    thermal: ThermalParams = field(default_factory=ThermalParams)
    drivetrain: DrivetrainParams = field(default_factory=DrivetrainParams)

    def __post_init__(self) -> None:
        fr = self.friction
        if fr.sign_speed > fr.stribeck_speed / 5.0:
            raise ParameterError("friction.sign_speed", f"must be <= friction.stribeck_speed/5 "
                                 f"= {fr.stribeck_speed / 5.0!r}, got {fr.sign_speed!r}")
        if fr.mu_min > fr.mu_ref:
            raise ParameterError("friction.mu_min", f"must be <= friction.mu_ref = "
                                 f"{fr.mu_ref!r}, got {fr.mu_min!r}")
        if fr.pressure_loss_at_ref > 0.0:
            limit = fr.pressure_ref / (2.0 * fr.pressure_loss_at_ref)
            if self.pack.max_pressure >= limit:
                raise ParameterError("clutch.max_pressure", f"must be < pressure_ref / "
                                     f"(2 pressure_loss_at_ref) = {limit!r} so that torque "
                                     f"grows with pressure, got {self.pack.max_pressure!r}")

    @classmethod
    def from_flat(cls, mapping: Mapping[str, Any], source: str | None = None) -> ClutchParams:
        """Build from dotted keys; ignores other namespaces, rejects typos/missing/bad values.

        ``source`` (e.g. a file name) is prefixed to error messages.
        """
        try:
            return cls._from_flat(mapping)
        except ParameterError as err:
            raise (err.with_source(source) if source else err) from None

    @classmethod
    def _from_flat(cls, mapping: Mapping[str, Any]) -> ClutchParams:
        if not isinstance(mapping, Mapping):
            raise ParameterError("<root>", f"expected a mapping of dotted keys, got "
                                 f"{type(mapping).__name__}")
        values: dict[str, dict[str, Any]] = {attr: {} for attr in _GROUPS}
        for key, value in mapping.items():
            if not isinstance(key, str) or key.split(".", 1)[0] not in NAMESPACES:
                continue
            spec = PARAMETER_SPECS.get(key)
            if spec is None:
                close = difflib.get_close_matches(key, PARAMETER_SPECS, n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise ParameterError(key, f"unknown model parameter{hint}")
            namespace, name = key.split(".", 1)
            values[NAMESPACES[namespace]][name] = spec.check(value)
        for key, spec in PARAMETER_SPECS.items():
            namespace, name = key.split(".", 1)
            if name not in values[NAMESPACES[namespace]]:
                if spec.default is None:
                    raise ParameterError(key, "missing (required)")
                values[NAMESPACES[namespace]][name] = spec.default
        return cls(**{attr: _GROUPS[attr](**kw) for attr, kw in values.items()})

    def to_flat(self) -> dict[str, Any]:
        """Return every key as a flat ``{dotted key: value}`` dict (inverse of from_flat)."""
        flat = {}
        for namespace, attr in NAMESPACES.items():
            group = getattr(self, attr)
            for f in fields(group):
                flat[f"{namespace}.{f.name}"] = getattr(group, f.name)
        return flat

    def replace(self, **dotted: Any) -> ClutchParams:
        """Return a validated copy with dotted keys changed.

        Example: ``params.replace(**{"spline.law": "none", "friction.mu_ref": 0.13})``.
        """
        return self.updated(dotted)

    def updated(self, changes: Mapping[str, Any]) -> ClutchParams:
        """Return a validated copy with the dotted keys of ``changes`` applied."""
        flat = self.to_flat()
        for key in changes:
            if key not in PARAMETER_SPECS:
                close = difflib.get_close_matches(str(key), PARAMETER_SPECS, n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise ParameterError(str(key), f"unknown model parameter{hint}")
        flat.update(changes)
        return ClutchParams.from_flat(flat)

    def with_law(self, law: str, slip_rpm: int = 10) -> ClutchParams:
        """Return a copy using ``law`` (ff_t/ff_v and printed forms: κ, τ of Table 7).

        ``slip_rpm`` must be 10 or 30 for ff_t/ff_v (the Table 7 columns); it is ignored for
        ``none`` and ``coulomb``, which keep the current gain/τ (unused by them).
        """
        row = law_info(law).table7
        if row is not None:
            entry = TABLE7.get((row, int(slip_rpm)))
            if entry is None:
                raise ParameterError("spline.law", f"Table 7 has no {law} column for "
                                     f"{slip_rpm} rpm (10 or 30)")
            return self.replace(**{"spline.law": law, "spline.gain": entry.gain_si,
                                   "spline.time_constant": entry.time_constant})
        return self.replace(**{"spline.law": law})
