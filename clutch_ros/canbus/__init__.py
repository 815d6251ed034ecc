"""The CAN layer of clutch_ros: DBC codec, bus factory, frames <-> RigState (no ROS here).

Modules:

* :mod:`~clutch_ros.canbus.dbc` -- :class:`RigDatabase` (strict DBC, SI decode/encode,
  CRC-8 SAE J1850).
* :mod:`~clutch_ros.canbus.pump_codec` -- :class:`PumpRequestCodec` (the pressure command
  frame: counter and checksum, its payload built directly where the DBC allows).
* :mod:`~clutch_ros.canbus.units` -- DBC bus units and their conversion to SI.
* :mod:`~clutch_ros.canbus.signal_map` -- which DBC message and signal feeds each RigState
  field and the pump command (``map.<field>`` parameters).
* :mod:`~clutch_ros.canbus.config` -- :class:`BusConfig` (also from node parameters),
  :func:`open_bus`, CAN filters.
* :mod:`~clutch_ros.canbus.bus` -- :class:`ReconnectingBus` (bus-off / unplugged adapter
  recovery with back-off, removal of the udp_multicast echo of our own frames).
* :mod:`~clutch_ros.canbus.udp` -- udp_multicast specifics: echo filter, group isolation and
  receive buffer of the socket.
* :mod:`~clutch_ros.canbus.batch` -- frames as plain tuples, read from a udp_multicast
  socket in batches (``ReconnectingBus.recv_batch``, the can_bridge's receive path).
* :mod:`~clutch_ros.canbus.fastdecode` -- :class:`FastDecoder`, the DBC decode from tables
  compiled per frame (the values of ``RigDatabase.decode``, bit for bit).
* :mod:`~clutch_ros.canbus.assembler` -- :class:`RigStateAssembler` (a ``can.Listener``)
  filling :class:`RigSample` (one RigState in SI units, with stale mask; defined in
  :mod:`clutch_ros.rigstate`).
* :mod:`~clutch_ros.canbus.pump_gate` -- :class:`PumpCommandGate` (PressureCommand -> PumpRequest,
  clamp, rate limit, watchdog).
* :mod:`~clutch_ros.canbus.logsource` -- :class:`LogSource` (ASC/BLF/any python-can log).
* :mod:`~clutch_ros.canbus.counters` -- frame counters, rates, rate limiter, RigState pacer.
* :mod:`~clutch_ros.canbus.errors` -- :class:`CanError` and its subclasses.

Benchmarks of this layer live outside the package: ``python -m benchmarks.can_decode``
(receive path) and ``python -m benchmarks.can_bridge_node`` (the can_bridge node process;
``--sustained``: 8,000 frames/s for a minute).
"""

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.bus import BusConfig, LinkState, ReconnectingBus, open_bus
from clutch_ros.canbus.dbc import RigDatabase
from clutch_ros.canbus.errors import (
    BusConfigError,
    BusUnavailable,
    CanError,
    DbcError,
    EncodeError,
    FrameDecodeError,
    LogFileError,
)
from clutch_ros.canbus.logsource import LogSource
from clutch_ros.canbus.pump_codec import PumpRequestCodec
from clutch_ros.canbus.pump_gate import GateOutput, PumpCommandGate, PumpGateConfig
from clutch_ros.rigstate import RigSample

__all__ = [
    "BusConfig",
    "BusConfigError",
    "BusUnavailable",
    "CanError",
    "DbcError",
    "EncodeError",
    "FrameDecodeError",
    "GateOutput",
    "LinkState",
    "LogFileError",
    "LogSource",
    "PumpCommandGate",
    "PumpGateConfig",
    "PumpRequestCodec",
    "ReconnectingBus",
    "RigDatabase",
    "RigSample",
    "RigStateAssembler",
    "open_bus",
]
