"""DBC bus units and their conversion to SI (REP 103; temperatures stay in degrees Celsius).

A DBC signal's unit string selects the factor that turns its physical (bus) value into SI:
``si_value = factor * bus_value``. The units are the one table of the package,
:data:`clutch_ros.interfaces.UNITS` (also behind the CSV and channel-map imports); a DBC
signal may use every unit of it that converts by a factor alone. ``params/rig.dbc`` uses
``bar``, ``rpm``, ``Nm``, ``degC``, ``V`` and ``A``; the other entries cover the spellings a
rig's own DBC commonly uses. Units with an offset (K) and times are not accepted: a signal
map entry gives the scale and offset to SI explicitly (``MESSAGE.SIGNAL * SCALE + OFFSET``,
see :mod:`clutch_ros.canbus.signal_map`).

==============================================  =======  =========================
DBC unit                                        SI unit  factor
==============================================  =======  =========================
``bar``, ``mbar``, ``Pa``, ``kPa``, ``MPa``      Pa       1e5, 100, 1, 1e3, 1e6
``psi``                                         Pa       6894.757293168361
``rpm``, ``1/min``, ``rad/s``, ``rads``         rad/s    2 pi / 60, 2 pi / 60, 1, 1
``N m``, ``Nm``, ``N.m``, ``N*m``, ``kN m``,    N m      1, 1, 1, 1, 1e3, 1e3
``kNm``
``degC``, ``°C``, ``C``                         degC     1
``V``, ``mV``                                   V        1, 1e-3
``A``, ``mA``                                   A        1, 1e-3
(none)                                          (none)   1 (counters, checksums, states, flags)
==============================================  =======  =========================
"""

from __future__ import annotations

from clutch_ros.interfaces import SI_UNITS, unit_table

__all__ = ["UNIT_TO_SI", "si_unit_of"]

#: DBC unit -> (SI unit, factor): ``si_value = factor * bus_value``.
UNIT_TO_SI: dict[str, tuple[str, float]] = {
    spelling: (SI_UNITS[unit.quantity], unit.scale)
    for spelling, unit in unit_table(offsets=False).items() if unit.quantity != "time"
}


def si_unit_of(unit: str) -> str | None:
    """Return the SI unit a DBC ``unit`` converts to, None when it is not in the table."""
    entry = UNIT_TO_SI.get(unit)
    return None if entry is None else entry[0]
