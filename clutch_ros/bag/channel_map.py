"""Channel maps: which measured channel (MDF4 channel or CSV column) feeds each RigState field.

A map is a YAML file; field names and their SI units come from :mod:`clutch_ros.rigstate`::

    time: {channel: t, unit: s}            # CSV: the time column (required); MDF4: optional,
                                           # default the time base of actuating_pressure
    fields:
      actuating_pressure: {channel: P_Kupplung, unit: bar}
      lamella_temperature: {channel: T_Lamelle, unit: degC}
      slip_speed: {channel: n_diff, unit: rpm}
      measured_torque: {channel: M_Welle, unit: N m}       # optional fields as wanted
      ff_voltages: {channels: [FF1, FF2, FF3, FF4, FF5, FF6, FF7, FF8], unit: V}

``actuating_pressure``, ``lamella_temperature`` and ``slip_speed`` are required (as for the
CSV import). Units are converted to SI by the field's quantity (:data:`UNITS`, from
:data:`clutch_ros.interfaces.UNITS`): bar, kPa, MPa, psi -> Pa; rpm -> rad/s; degC, K -> °C;
N m, kN m -> N m; mV -> V; mA -> A; ms, us, ns -> s. A
channel whose own unit (MDF4 stores one) disagrees with the map is an error, never a silent
rescale. ``has_measured_torque`` is true where the measured torque is finite.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from clutch_ros.bag.errors import MapError
from clutch_ros.interfaces import NS_PER_S, SI_UNITS, unit_table
from clutch_ros.rigstate import FIELDS

__all__ = ["ChannelMap", "MapError", "REQUIRED_FIELDS", "UNITS", "load_map", "samples"]

REQUIRED_FIELDS = ("actuating_pressure", "lamella_temperature", "slip_speed")
#: quantity -> unit spelling -> (scale, offset): SI = value * scale + offset, from the one
#: unit table :data:`clutch_ros.interfaces.UNITS`
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    quantity: {spelling: (u.scale, u.offset) for spelling, u in unit_table(quantity).items()}
    for quantity in SI_UNITS if quantity
}
_SPECS = {f.name: f for f in FIELDS}


@dataclass(frozen=True)
class Source:
    """The channels of one field: names (one per array element), unit and SI conversion."""

    field: str
    channels: tuple[str, ...]
    unit: str
    scale: float
    offset: float


@dataclass(frozen=True)
class ChannelMap:
    """A validated map (see module docstring)."""

    path: Path
    time: Source | None
    fields: tuple[Source, ...]

    def channels(self) -> list[str]:
        """Return every channel the map reads (time first when given)."""
        out = list(self.time.channels) if self.time else []
        for src in self.fields:
            out += src.channels
        return out


def _source(path: Path, name: str, entry: Any, quantity: str, count: int | None) -> Source:
    if not isinstance(entry, Mapping):
        raise MapError(path, f"{name}: expected a mapping with channel(s) and unit")
    unknown = set(entry) - {"channel", "channels", "unit"}
    if unknown:
        raise MapError(path, f"{name}: unknown key(s) {', '.join(sorted(unknown))}")
    if count is None:
        if not isinstance(entry.get("channel"), str):
            raise MapError(path, f"{name}: 'channel' (one name) is required")
        channels = (entry["channel"],)
    else:
        channels = tuple(entry.get("channels") or ())
        if len(channels) != count or not all(isinstance(c, str) for c in channels):
            raise MapError(path, f"{name}: 'channels' must list {count} names")
    unit = str(entry.get("unit", ""))
    table = UNITS[quantity]
    if unit not in table:
        raise MapError(path, f"{name}: unit {unit!r} is not a {quantity} unit "
                             f"({', '.join(table)})")
    return Source(name, channels, unit, *table[unit])


def load_map(path: str | Path) -> ChannelMap:
    """Read and validate the map YAML ``path``; raise :class:`MapError` naming the problem."""
    path = Path(path)
    try:
        tree = yaml.safe_load(path.read_text())
    except OSError as err:
        raise MapError(path, f"cannot read: {err.strerror or err}") from err
    except yaml.YAMLError as err:
        raise MapError(path, f"not valid YAML: {err}") from err
    if not isinstance(tree, Mapping) or not isinstance(tree.get("fields"), Mapping):
        raise MapError(path, "expected a mapping with 'fields' (and optionally 'time')")
    sources = []
    for name, entry in tree["fields"].items():
        spec = _SPECS.get(name)
        if spec is None or spec.kind == "flag":
            known = ", ".join(f.name for f in FIELDS if f.kind != "flag")
            raise MapError(path, f"fields: {name!r} is not a RigState field ({known})")
        count = len(spec.csv_stems) if spec.kind == "array" else None
        sources.append(_source(path, name, entry, spec.quantity, count))
    missing = [f for f in REQUIRED_FIELDS if f not in tree["fields"]]
    if missing:
        raise MapError(path, f"fields: required field(s) {', '.join(missing)} not mapped")
    time = _source(path, "time", tree["time"], "time", None) if "time" in tree else None
    return ChannelMap(path, time, tuple(sources))


def samples(cmap: ChannelMap, t_s: np.ndarray, columns: Mapping[str, np.ndarray],
            offset_ns: int = 0) -> Iterator[tuple[int, dict[str, Any]]]:
    """Yield ``(stamp_ns, fields)`` in SI from raw ``columns`` (channel -> values at ``t_s``).

    ``t_s`` [s] must increase strictly (checked); stamps are ``t_s`` + ``offset_ns``.
    """
    t_s = np.asarray(t_s, dtype=float)
    if len(t_s) == 0:
        raise MapError(cmap.path, "the source has no samples")
    if not np.all(np.isfinite(t_s)) or np.any(np.diff(t_s) <= 0.0):
        raise MapError(cmap.path, "the time base does not increase strictly")
    si = {}
    for src in cmap.fields:
        arrays = [np.asarray(columns[c], dtype=float) * src.scale + src.offset
                  for c in src.channels]
        si[src.field] = arrays
    stamps = np.round(t_s * NS_PER_S).astype(np.int64) + int(offset_ns)
    for i, stamp in enumerate(stamps):
        fields: dict[str, Any] = {}
        for src in cmap.fields:
            values = [float(a[i]) for a in si[src.field]]
            fields[src.field] = values if len(src.channels) > 1 else values[0]
        if "measured_torque" in fields:
            fields["has_measured_torque"] = math.isfinite(fields["measured_torque"])
        yield int(stamp), fields
