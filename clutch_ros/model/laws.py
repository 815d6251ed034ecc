"""The spline-friction law registry: every law, and all the model knows about it, in one table.

A law is one :class:`SplineLawInfo` in :data:`_REGISTRY` (filled below, one
:func:`register` call per law) plus its class (a :class:`~clutch_ros.model.spline.SplineLaw`
in its own module, named here as ``"module:Class"`` and imported on first use, so this module
stays at the bottom of the model's imports: ``params`` reads it). Every other module reads the
registry, none spells a list of law names:

- ``params``: the ``spline.law`` choices, :data:`~clutch_ros.model.params.SPLINE_LAWS` and
  ``PASSIVE_LAWS`` (live views, :class:`LawNames`), and ``with_law``'s Table 7 row;
- ``pack``: the law object (:func:`make_spline_law`);
- ``kernel``: the compiled loop's code of the law (:attr:`SplineLawInfo.kernel`;
  ``LAW_CODES``);
- ``adaptation``: whether ``spline.gain`` may be adapted (``GAIN_LAWS``);
- ``identification`` / ``fit_data``: the fitted parameters (``FREE_PARAMETERS``), the unit of
  the gain, the start values and the sample budget (``SAMPLE_BUDGET``).

Passive laws never do positive work on a lamella (F·Δz ≥ 0); the ``*_printed`` laws are the
thesis's Eqs. 29-30 as printed (not passive, for reproducing the thesis only).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Any, overload

from clutch_ros.model import kernel_box
from clutch_ros.model.errors import UnknownLawError

__all__ = ["SplineLawInfo", "LawNames", "LawTable", "register", "law_info", "law_names",
           "make_spline_law", "FRICTION_PARAMETERS"]

#: Fitted for every law: the friction law (the pack damping follows the law's own keys).
FRICTION_PARAMETERS = ("friction.mu_ref", "friction.temperature_slope",
                       "friction.pressure_loss_at_ref")
_DAMPING = ("clutch.lamella_damping",)


@dataclass(frozen=True)
class SplineLawInfo:
    """One spline-friction law (the value of ``spline.law``) and what the model needs of it.

    Attributes:
        name: the value of ``spline.law``.
        law_class: the :class:`~clutch_ros.model.spline.SplineLaw` subclass, or its
            ``"module:Class"`` path (imported on first use).
        passive: never does positive work on a lamella (F·Δz ≥ 0 on every step).
        kernel: ``(kind, box variant)`` of the compiled loop (:mod:`~.kernel_box` codes);
            None: the loop has no code for it (``engine="kernel"`` raises
            :class:`~clutch_ros.model.errors.KernelUnavailableError`, ``"auto"`` runs numpy).
        gain_unit: SI unit of ``spline.gain`` for this law; None: the law has no gain.
        adapts_gain: the adaptation may estimate (scale) its gain (the passive laws with a
            gain; a printed law's gain is left as given).
        table7: the Table 7 row (``"ff_t"``/``"ff_v"``) whose κ, τ ``with_law`` and the fit's
            start take; None: the law keeps the base's gain and τ.
        free_parameters: dotted keys identification fits for this law, in fit order.
        start: ``(key, value)`` start values for the fit where the base has no positive value.
        sample_budget: decimated samples per residual evaluation of a fit (its cost per
            sample sets it: a box step costs more than a linear one).
        description: one line for help texts.
    """

    name: str
    law_class: type[Any] | str
    passive: bool
    kernel: tuple[int, int] | None = None
    gain_unit: str | None = None
    adapts_gain: bool = False
    table7: str | None = None
    free_parameters: tuple[str, ...] = FRICTION_PARAMETERS + _DAMPING
    start: tuple[tuple[str, float], ...] = ()
    sample_budget: int = 20_000
    description: str = ""

    @property
    def has_gain(self) -> bool:
        """True when ``spline.gain`` is the law's gain (it has a unit)."""
        return self.gain_unit is not None

    def load(self) -> type[Any]:
        """Return the law's class (imports its module the first time)."""
        if isinstance(self.law_class, str):
            module, _, attr = self.law_class.partition(":")
            cls: type[Any] = getattr(importlib.import_module(module), attr)
            return cls
        return self.law_class


_REGISTRY: dict[str, SplineLawInfo] = {}


def register(info: SplineLawInfo) -> SplineLawInfo:
    """Add a law to the registry (its name must be new); return ``info``."""
    if info.name in _REGISTRY:
        raise ValueError(f"spline law {info.name!r} is registered already")
    _REGISTRY[info.name] = info
    return info


def law_info(name: str) -> SplineLawInfo:
    """Return the registered law ``name``; raise :class:`UnknownLawError` if there is none."""
    info = _REGISTRY.get(name)
    if info is None:
        raise UnknownLawError(name, tuple(_REGISTRY))
    return info


def law_names(where: str | Callable[[SplineLawInfo], object] | None = None) -> tuple[str, ...]:
    """Return the registered law names (in registration order) that ``where`` selects.

    ``where``: None (all), a field name of :class:`SplineLawInfo` (the laws where it is
    truthy: ``"passive"``, ``"adapts_gain"``, ``"kernel"``) or a predicate on the info.
    """
    if isinstance(where, str):
        where = attrgetter(where)
    return tuple(n for n, info in _REGISTRY.items() if where is None or where(info))


# Typed loosely on purpose: the registry sits below params (ClutchParams) and the law classes
# (SplineLaw), which read it; naming them here would close an import cycle. PackModel
# annotates the law it gets.
def make_spline_law(params: Any) -> Any:
    """Return a fresh law object for ``params.spline.law`` (one per PackModel)."""
    return law_info(params.spline.law).load()(params)


class LawNames(Sequence[str]):
    """A live, read-only tuple of the registered law names whose field ``where`` is truthy.

    Compares equal to a tuple of the same names; a law registered later appears in it.
    ``where``: a field name of :class:`SplineLawInfo` (None: every law). Picklable.
    """

    def __init__(self, where: str | None = None) -> None:
        self._where = where

    def _names(self) -> tuple[str, ...]:
        return law_names(self._where)

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> tuple[str, ...]: ...

    def __getitem__(self, index: int | slice) -> str | tuple[str, ...]:
        return self._names()[index]

    def __len__(self) -> int:
        return len(self._names())

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._names()

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (LawNames, tuple, list)):
            return self._names() == tuple(other)
        return NotImplemented

    def __hash__(self) -> int:
        return hash(self._names())

    def __repr__(self) -> str:
        return repr(self._names())


class LawTable(Mapping[str, Any]):
    """A live, read-only ``{law name: info.<field>}`` mapping over the registry.

    ``where``: as for :class:`LawNames` (the laws whose field ``where`` is truthy). Picklable.
    """

    def __init__(self, field: str, where: str | None = None) -> None:
        self._field = field
        self._where = where

    def __getitem__(self, name: str) -> Any:
        if not isinstance(name, str) or name not in law_names(self._where):
            raise KeyError(name)
        return getattr(_REGISTRY[name], self._field)

    def __iter__(self) -> Iterator[str]:
        return iter(law_names(self._where))

    def __len__(self) -> int:
        return len(law_names(self._where))

    def __repr__(self) -> str:
        return repr(dict(self))


# -- the laws (one entry each; the class lives in its own module) ----------------------------
_SPLINE = "clutch_ros.model.spline"
_PASSIVE = "clutch_ros.model.spline_passive"
_FILTER_FIT = FRICTION_PARAMETERS + ("spline.gain", "spline.time_constant") + _DAMPING

register(SplineLawInfo(
    "none", f"{_SPLINE}:SplineLaw", passive=True, kernel=(kernel_box.NONE, 0),
    description="no spline friction (the Eq. 1 pack)"))
register(SplineLawInfo(
    "ff_t", f"{_PASSIVE}:PassiveTorqueFilterLaw", passive=True,
    kernel=(kernel_box.BOX, kernel_box.FF_T), gain_unit="1/m", adapts_gain=True,
    table7="ff_t",
    free_parameters=_FILTER_FIT, sample_budget=5_000,
    description="Eq. 29 made passive: high-passed torque"))
register(SplineLawInfo(
    "ff_v", f"{_PASSIVE}:PassiveViscousLaw", passive=True,
    kernel=(kernel_box.BOX, kernel_box.FF_V), gain_unit="s/m^2", adapts_gain=True,
    table7="ff_v",
    free_parameters=_FILTER_FIT, sample_budget=5_000,
    description="Eq. 30 made passive: torque times low-passed lamella speed"))
register(SplineLawInfo(
    "coulomb", f"{_SPLINE}:CoulombLaw", passive=True,
    kernel=(kernel_box.BOX, kernel_box.COULOMB),
    free_parameters=FRICTION_PARAMETERS + ("spline.friction_coefficient",) + _DAMPING,
    start=(("spline.friction_coefficient", 0.05),), sample_budget=4_000,
    description="spline stiction bounded by mu_s R_e / r_s times the normal forces"))
register(SplineLawInfo(
    "ff_t_printed", f"{_SPLINE}:TorqueFilterLaw", passive=False,
    kernel=(kernel_box.LINEAR, 0), gain_unit="1/m", table7="ff_t",
    free_parameters=_FILTER_FIT, sample_budget=20_000,
    description="Eq. 29 as printed (not passive, thesis reproduction only)"))
register(SplineLawInfo(
    "ff_v_printed", f"{_SPLINE}:ViscousLaw", passive=False,
    kernel=(kernel_box.VISCOUS, 0), gain_unit="s/m^2", table7="ff_v",
    free_parameters=_FILTER_FIT, sample_budget=15_000,
    description="Eq. 30 as printed (not passive, thesis reproduction only)"))
