"""A python-can interface whose adapter the test can unplug, for ReconnectingBus tests.

``FlakyBus`` is a real :class:`can.BusABC` subclass registered as interface ``flaky``; the
"wire" underneath is a virtual bus on ``<channel>-wire``. ``ADAPTERS[channel]`` is the
adapter the test controls: unplug it and opening, receiving and sending fail like a USB
adapter pulled out of the rig PC (CanInitializationError / CanOperationError / OSError).
"""

from dataclasses import dataclass, field

import can


@dataclass
class Adapter:
    plugged: bool = True
    fail_send: bool = False
    state: can.BusState = can.BusState.ACTIVE
    open_attempts: list = field(default_factory=list)  # clock times of open attempts
    clock: object = None


ADAPTERS: dict[str, Adapter] = {}


class FlakyBus(can.BusABC):
    def __init__(self, channel, **kwargs):
        self.adapter = ADAPTERS[channel]
        self.adapter.open_attempts.append(self.adapter.clock() if self.adapter.clock else None)
        if not self.adapter.plugged:
            raise can.CanInitializationError(f"adapter {channel} not found")
        self.adapter.state = can.BusState.ACTIVE
        self._wire = can.Bus(interface="virtual", channel=f"{channel}-wire",
                             receive_own_messages=False)
        self.channel_info = f"flaky {channel}"
        super().__init__(channel=channel, **kwargs)

    def _recv_internal(self, timeout):
        if not self.adapter.plugged:
            raise OSError(19, "No such device")
        return self._wire.recv(timeout), False

    def send(self, msg, timeout=None):
        if not self.adapter.plugged:
            raise can.CanOperationError("device disconnected")
        if self.adapter.fail_send:
            raise can.CanOperationError("transmit buffer full (no ACK)")
        self._wire.send(msg, timeout)

    @property
    def state(self):
        return self.adapter.state

    def shutdown(self):
        super().shutdown()
        self._wire.shutdown()


class PickyBus(can.BusABC):
    """An interface that takes no keyword arguments (python-can passes some: TypeError)."""

    def __init__(self, channel):
        super().__init__(channel=channel)

    def _recv_internal(self, timeout):
        return None, False

    def send(self, msg, timeout=None):
        pass
