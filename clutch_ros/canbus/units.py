"""DBC bus units and their conversion to SI (REP 103; temperatures stay in degrees Celsius).

A DBC signal's unit string selects the factor that turns its physical (bus) value into SI:
``si_value = factor * bus_value``. ``params/rig.dbc`` uses ``bar``, ``rpm``, ``Nm``,
``degC``, ``V`` and ``A``; the other entries cover the spellings a rig's own DBC commonly
uses. Units with an offset (K, degF) are not in the table: a signal map entry gives the
scale and offset to SI explicitly (``MESSAGE.SIGNAL * SCALE + OFFSET``, see
:mod:`clutch_ros.canbus.signal_map`).

==========================================  =======  =====================
DBC unit                                    SI unit  factor
==========================================  =======  =====================
``bar``, ``mbar``, ``Pa``, ``kPa``, ``MPa``  Pa       1e5, 100, 1, 1e3, 1e6
``psi``                                     Pa       6894.757293168
``rpm``, ``1/min``, ``rad/s``               rad/s    2 pi / 60, 2 pi / 60, 1
``Nm``, ``N m``, ``N.m``, ``kNm``           N m      1, 1, 1, 1e3
``degC``, ``°C``, ``C``                     degC     1
``V``, ``mV``                               V        1, 1e-3
``A``, ``mA``                               A        1, 1e-3
(none)                                      (none)   1 (counters, checksums, states, flags)
==========================================  =======  =====================
"""

from __future__ import annotations

import math

__all__ = ["UNIT_TO_SI", "si_unit_of"]

_RPM = 2.0 * math.pi / 60.0

#: DBC unit -> (SI unit, factor): ``si_value = factor * bus_value``.
UNIT_TO_SI: dict[str, tuple[str, float]] = {
    "bar": ("Pa", 1e5), "mbar": ("Pa", 100.0), "Pa": ("Pa", 1.0), "kPa": ("Pa", 1e3),
    "MPa": ("Pa", 1e6), "psi": ("Pa", 6894.757293168),
    "rpm": ("rad/s", _RPM), "1/min": ("rad/s", _RPM), "rad/s": ("rad/s", 1.0),
    "Nm": ("N m", 1.0), "N m": ("N m", 1.0), "N.m": ("N m", 1.0), "kNm": ("N m", 1e3),
    "degC": ("degC", 1.0), "°C": ("degC", 1.0), "C": ("degC", 1.0),
    "V": ("V", 1.0), "mV": ("V", 1e-3),
    "A": ("A", 1.0), "mA": ("A", 1e-3),
    "": ("", 1.0),
}


def si_unit_of(unit: str) -> str | None:
    """Return the SI unit a DBC ``unit`` converts to, None when it is not in the table."""
    entry = UNIT_TO_SI.get(unit)
    return None if entry is None else entry[0]
