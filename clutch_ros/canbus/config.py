"""Which CAN bus to open: :class:`BusConfig` (validated), :func:`open_bus`, CAN filters.

:class:`BusConfig` holds what the nodes' ``can.*`` parameters choose (interface, channel,
bitrate, filters, ...) and validates it; :func:`open_bus` opens it with python-can, ignoring
python-can config files so a run is reproducible (and tuning udp_multicast sockets:
:func:`clutch_ros.canbus.udp.tune_udp_multicast`). :mod:`clutch_ros.canbus.bus` re-exports
all three.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import can.interfaces

from clutch_ros.canbus.errors import BusConfigError, BusUnavailable
from clutch_ros.canbus.udp import tune_udp_multicast

__all__ = ["BusConfig", "open_bus", "parse_filters"]

_RESERVED = {"interface", "channel", "bitrate", "receive_own_messages", "can_filters", "fd"}

def parse_filters(specs: Sequence[str | Mapping[str, Any]]) -> tuple[dict[str, Any], ...]:
    """Parse CAN filters: dicts (python-can form) or strings ``"ID:MASK"`` / ``"ID:MASK:x"``.

    IDs and masks accept any int literal (``0x100``). ``:x`` marks a 29-bit filter. Raises
    :class:`BusConfigError` for malformed entries.
    """
    out = []
    for spec in specs:
        if isinstance(spec, str):
            parts = spec.strip().split(":")
            if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != "x"):
                raise BusConfigError(f"CAN filter {spec!r} is not 'ID:MASK' or 'ID:MASK:x'")
            try:
                entry: dict[str, Any] = {"can_id": int(parts[0], 0), "can_mask": int(parts[1], 0)}
            except ValueError as err:
                raise BusConfigError(f"CAN filter {spec!r}: {err}") from err
            if len(parts) == 3:
                entry["extended"] = True
        elif isinstance(spec, Mapping):
            entry = dict(spec)
        else:
            raise BusConfigError(f"CAN filter {spec!r} is neither a string nor a mapping")
        can_id, mask = entry.get("can_id"), entry.get("can_mask")
        if not isinstance(can_id, int) or not isinstance(mask, int):
            raise BusConfigError(f"CAN filter {spec!r} needs integer can_id and can_mask")
        if not (0 <= can_id < 1 << 29 and 0 <= mask < 1 << 29):
            raise BusConfigError(f"CAN filter {spec!r}: id and mask must be 0..0x1FFFFFFF")
        if set(entry) - {"can_id", "can_mask", "extended"}:
            raise BusConfigError(f"CAN filter {spec!r} has unknown keys")
        out.append(entry)
    return tuple(out)


@dataclass(frozen=True)
class BusConfig:
    """Which CAN bus to open (validated on construction; raises :class:`BusConfigError`).

    ``interface``: a python-can interface name (socketcan, vector, pcan, kvaser,
    udp_multicast, virtual, ...); ``channel``: interface specific (``can0``, ``0``,
    ``PCAN_USBBUS1``, a multicast group, any name for virtual); ``bitrate`` [bit/s] or None
    for the interface default; ``data_bitrate`` [bit/s] for the CAN FD data phase;
    ``can_filters``: python-can filter dicts or ``"ID:MASK[:x]"`` strings; ``fd``: None keeps
    the interface default; ``extra``: further interface keyword arguments (e.g. ``port`` for
    udp_multicast, ``app_name`` for vector).
    """

    interface: str = "virtual"
    channel: str | int | None = "clutch_rig"
    bitrate: int | None = None
    receive_own_messages: bool = False
    can_filters: tuple[dict[str, Any], ...] | None = None
    fd: bool | None = None
    data_bitrate: int | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.interface, str) or self.interface not in can.interfaces.BACKENDS:
            raise BusConfigError(
                f"unknown CAN interface {self.interface!r}; python-can knows: "
                f"{', '.join(sorted(can.interfaces.BACKENDS))}"
            )
        for name in ("bitrate", "data_bitrate"):
            value = getattr(self, name)
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= 20_000_000
            ):
                raise BusConfigError(f"{name} must be a positive int [bit/s], got {value!r}")
        if self.data_bitrate is not None and not self.fd:
            raise BusConfigError("data_bitrate needs fd=True")
        if self.can_filters is not None:
            object.__setattr__(self, "can_filters", parse_filters(self.can_filters))
        if not isinstance(self.extra, Mapping) or set(self.extra) & _RESERVED:
            raise BusConfigError(f"extra must be a mapping without the keys {sorted(_RESERVED)}")
        if self.receive_own_messages and self.interface == "udp_multicast":
            raise BusConfigError("udp_multicast does not support receive_own_messages")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> BusConfig:
        """Build from the nodes' flat ``can.*`` parameters (absent keys keep the defaults).

        Keys: ``can.interface``, ``can.channel``, ``can.port`` (udp_multicast only),
        ``can.bitrate`` (0: interface default), ``can.fd`` (False: interface default),
        ``can.receive_own_messages``, ``can.filters`` (``"ID:MASK[:x]"``; empty strings are
        ignored: a ROS string array cannot be empty).
        """
        interface = params.get("can.interface", cls.interface)
        port = params.get("can.port")
        filters = [f for f in params.get("can.filters", ()) if f]
        return cls(interface=interface, channel=params.get("can.channel", cls.channel),
                   bitrate=params.get("can.bitrate") or None, fd=params.get("can.fd") or None,
                   receive_own_messages=bool(params.get("can.receive_own_messages", False)),
                   can_filters=parse_filters(filters) if filters else None,
                   extra={"port": port} if interface == "udp_multicast" and port else {})

    def kwargs(self) -> dict[str, Any]:
        """Return the keyword arguments for :func:`can.Bus`."""
        kwargs: dict[str, Any] = {
            "interface": self.interface,
            "channel": self.channel,
            "receive_own_messages": self.receive_own_messages,
        }
        if self.bitrate is not None:
            kwargs["bitrate"] = self.bitrate
        if self.data_bitrate is not None:
            kwargs["data_bitrate"] = self.data_bitrate
        if self.fd is not None:
            kwargs["fd"] = self.fd
        if self.can_filters:
            kwargs["can_filters"] = [dict(f) for f in self.can_filters]
        kwargs.update(self.extra)
        return kwargs

    def describe(self) -> str:
        """Return ``interface:channel`` for messages."""
        return f"{self.interface}:{self.channel}"


def open_bus(config: BusConfig) -> can.BusABC:
    """Open the bus described by ``config`` (python-can config files are ignored).

    Raises :class:`BusUnavailable` when the interface driver is missing or the device cannot
    be opened, :class:`BusConfigError` when python-can rejects the arguments.
    """
    try:
        bus = can.Bus(ignore_config=True, **config.kwargs())
    except (TypeError, NotImplementedError) as err:
        if isinstance(err, can.CanInterfaceNotImplementedError):
            raise BusUnavailable(
                f"{config.describe()}: interface not available: {err}"
            ) from err
        raise BusConfigError(f"{config.describe()}: invalid bus arguments: {err}") from err
    except ValueError as err:
        raise BusConfigError(f"{config.describe()}: invalid bus arguments: {err}") from err
    except Exception as err:  # CanError, OSError, ImportError, struct.error, driver errors
        raise BusUnavailable(
            f"{config.describe()}: cannot open bus: {type(err).__name__}: {err}"
        ) from err
    if config.interface == "udp_multicast":
        tune_udp_multicast(bus)
    return bus
