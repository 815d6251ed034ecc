"""The can_bridge's receive side: CAN frames -> live sample -> ``rig_state``.

Frames are read on a receive thread from configure on (counted and decoded into the live
sample, diagnosed), and published only while active. The thread takes every frame
queued at a wake-up as plain tuples (:meth:`~clutch_ros.canbus.ReconnectingBus.recv_batch`:
on udp_multicast no python-can Message per frame) and decodes rig frames from tables
compiled from the DBC (:mod:`clutch_ros.canbus.fastdecode`); foreign identifiers are counted
and never decoded. With ``bridge.publish_on``, after a batch the thread leaves the frames
queued in the socket until just after the pacer can publish again (``HOLD_MARGIN``,
:meth:`~clutch_ros.canbus.counters.PublishPacer.until_allowed`), then reads them in one
batch, paced on their bus times as before: ~130 reads/s at the demo's 2,500 frames/s instead
of ~900 (each wake-up had cost more CPU than the frames it read). Each frame takes
one path: the assembler decodes it into the live sample, the pacer decides, the sample
becomes ``rig_state`` stamped with the newest contributing frame's bus time: at once when
the ``bridge.publish_on`` frame arrives (at most ``bridge.rate``), or on a ``bridge.rate``
timer when that is empty. Stale signal groups are flagged in ``stale_mask``, aged at the
sample's own stamp (the newest frame's bus time), as in a log replay: a group is stale when it
fell behind the rest of the bus, not when this node ran late. How late the node publishes
(wall clock minus the sample's stamp) is reported apart, as ``receive_lag_max_s`` on
/diagnostics (a WARN above ``LAG_WARN``): on a loaded 2-core machine the bridge fell 80-110 ms
behind a healthy bus, and ageing against the wall clock flagged every sample of that backlog
stale, which removed the torque measurement from coherent data.

:class:`ReceiveSide` holds these methods of :class:`~clutch_ros.nodes.can_bridge.CanBridgeNode`
(a mixin: the node's state, lock and publishers are its own); the send side is
:mod:`clutch_ros.nodes.can_bridge_send`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import can

from clutch_ros.canbus.batch import RawFrame, frame_message
from clutch_ros.canbus.intake import Columns, frame_at
from clutch_ros.nodes.can_bridge_state import BridgeState
from clutch_ros.nodes.convert import can_frame_to_ros
from clutch_ros.nodes.lockstep import time_of_frame

__all__ = ["FLUSH_PERIOD", "HOLD_MARGIN", "ReceiveSide"]

FLUSH_PERIOD = 0.05  # [s] with publish_on: a frame held back by bridge.rate goes out then
#: [s] with publish_on, the receive thread leaves the frames queued in the socket until this
#: long before the pacer can publish again (each wake-up cost more CPU than its frames);
#: negative: until just after, when the trigger frame due then is mostly queued already (one
#: read per sample instead of ~2, for at most 0.3 ms of rig_state latency: RESULTS.md)
HOLD_MARGIN = -0.0003


class ReceiveSide:
    """The receive thread's methods of the can_bridge node (module docstring)."""

    # the node's (CanBridgeNode.__init__ and on_configure make them)
    state: BridgeState
    _lock: threading.Lock
    _rx_stop: threading.Event
    _sim_time: bool
    _time_floor: float
    _cfg: Any
    _raw_pub: Any
    _rig_pub: Any
    _rig_encode: Callable[..., Any]
    _node_time: Callable[[], float]
    get_logger: Callable[[], Any]

    def _on_link_event(self, event) -> None:  # the bus rate-limits its own log lines
        if event.new == "closed":
            return
        log = self.get_logger()
        if event.new == "up":
            log.info(f"CAN link {event.old} -> up", throttle_duration_sec=10.0)
        else:
            log.warning(f"CAN link {event.old} -> {event.new}: {event.reason}",
                        throttle_duration_sec=10.0)

    def _receive(self, bus) -> None:
        """Receive thread: batches of frames from ``bus`` into :meth:`_on_frames`.

        With the compiled intake the batches come as columns (``recv_columns``: one system
        call and one compiled parse per batch on udp_multicast), else as tuples.
        """
        stop, on_frames = self._rx_stop, self._on_frames
        intake = self.state.intake
        recv = bus.recv_columns if intake is not None and intake.ready else bus.recv_batch
        while not stop.is_set():
            try:
                frames = recv(0.1)
            except can.CanOperationError:  # shut down
                return
            except Exception as err:  # noqa: BLE001 - counted; the thread must live
                if self.state.assembler is not None:
                    self.state.assembler.on_error(err)
                stop.wait(0.01)
                continue
            if frames:
                on_frames(frames)
                hold = self._hold()
                if hold > 0.0:
                    stop.wait(hold)

    def _hold(self) -> float:
        """How long [s] the receive thread may leave frames queued: see HOLD_MARGIN."""
        st = self.state
        pacer, assembler, offset = st.pacer, st.assembler, st.offset
        assert pacer is not None and assembler is not None  # configured
        newest = assembler.newest_time
        if pacer.trigger is None or newest is None or offset is None or not st.active:
            return 0.0
        with self._lock:
            wait = pacer.until_allowed(newest)
        # at most FLUSH_PERIOD: at a low bridge.rate a full bus would fill the socket buffer
        return min(newest + offset + wait - HOLD_MARGIN - time.time(), 1.0 / pacer.rate,
                   FLUSH_PERIOD)

    def _on_frames(self, frames: list[RawFrame] | Columns) -> None:
        """Receive thread: frames -> live sample -> (pacer) -> rig_state when active.

        With the compiled intake (``bridge.compiled``, :mod:`clutch_ros.canbus.intake`) its
        kernel takes the runs of clean rig frames, publishing where the pacer says; each
        other frame goes through :meth:`_feed_frames`, as every frame does without it.
        """
        st = self.state
        intake, pacer = st.intake, st.pacer
        if isinstance(frames, Columns):
            cols: Columns | None = frames
        else:
            cols = intake.columns(frames) if intake is not None and intake.ready else None
        if intake is None or cols is None:
            self._feed_frames(frames if isinstance(frames, list) else _frames(frames))
            return
        assert pacer is not None  # configured with the intake
        i, n = 0, cols.stamp.size
        while i < n:
            try:
                with self._lock:  # (the pacer's, as in _feed_frames; see _halt)
                    i, key = intake.run(cols, i, st.active)
            except Exception as err:  # noqa: BLE001 - nothing was taken: the Python path
                assert st.assembler is not None
                st.assembler.on_error(err)
                self._feed_frames(_frames(cols)[i:])
                return
            if key >= 0:
                try:  # (as in _feed_frames: counted; the receive thread must live)
                    self._publish_latest(pacer.on_frame, key, bus_time=True)
                except Exception as err:  # noqa: BLE001 - e.g. the context shut down
                    assert st.assembler is not None
                    st.assembler.on_error(err)
            elif i < n:  # no clean rig frame: the Python path, then the kernel again
                self._feed_frames([frame_at(cols, i)])
                i += 1

    def _feed_frames(self, frames: list[RawFrame]) -> None:
        """Frames -> live sample -> (pacer) -> rig_state when active, in Python.

        A batch at a time: what stays the same from configure to cleanup is looked up once.
        """
        st = self.state
        assembler, gate, pacer = st.assembler, st.gate, st.pacer
        # the thread starts after configure made them, and stops before cleanup
        assert assembler is not None and gate is not None and pacer is not None
        feed, pump_key, trigger, fallback = (assembler.feed_frame, gate.codec.spec.key,
                                             pacer.trigger, pacer.fallback)
        for frame in frames:
            try:
                if self._sim_time:  # received at the node's (simulated) time, not the PC's
                    tick = time_of_frame(frame[1], frame[2], frame[7])
                    if tick is not None:  # a lock-step rig's time frame: the frames after it
                        self._time_floor = max(self._time_floor, tick)
                        continue
                    frame = (self._node_time(), *frame[1:])
                key = feed(*frame)
                if not st.active:
                    continue
                if self._raw_pub is not None:
                    raw = can_frame_to_ros(frame_message(frame), st.offset or 0.0)
                    with self._lock:  # (see _halt)
                        if st.active:
                            self._raw_pub.publish(raw)
                if key is None:
                    continue
                if key == pump_key:  # ours never come back (echoes removed)
                    st.foreign_pump_requests += 1
                if key != trigger:  # no other frame publishes, but a missing trigger's
                    # fallback (counters.PublishPacer); a rig frame while the trigger flows
                    # (all but ~1 in 22) is only counted, without the lock and clock of a
                    # publication
                    if key not in fallback or trigger is None:
                        continue
                    newest = assembler.newest_time  # (None: nothing decoded, nothing new)
                    if newest is None or not pacer.fallback_due(key, newest):
                        continue
                else:  # a trigger the cap holds back (9 in 10 at 1 kHz): the pacer's state only
                    newest = assembler.newest_time
                    if newest is not None:
                        with self._lock:
                            if pacer.trigger_held(newest):
                                continue
                self._publish_latest(pacer.on_frame, key, bus_time=True)
            except Exception as err:  # noqa: BLE001 - counted; the receive thread must live
                assembler.on_error(err)

    def _replay(self) -> None:
        st = self.state
        source, stop, assembler, rig_pub = st.source, st.stop, st.assembler, self._rig_pub
        assert source is not None and assembler is not None and rig_pub is not None  # (log)
        # the writer's own matched readers, not the graph's count: a reader the graph knows
        # may not be matched by the writer yet, and what is sent before is lost to it
        while rig_pub.get_subscription_count() < self._cfg["input.wait_for_subscribers"]:
            if stop.wait(0.05):
                return
        try:
            for sample in source.samples(assembler, 1.0 / self._cfg["bridge.rate"], stop):
                if st.offset is None and source.first_time is not None:
                    st.offset = time.time() - source.first_time
                self._publish(sample)
            self.get_logger().info(f"log {source.path} done: {source.frames_read} frames, "
                                   f"{st.published} rig_state published")
        except Exception as err:  # noqa: BLE001 - report, never crash the node
            self.get_logger().error(f"log replay stopped: {err}")

    def _publish_latest(self, decide, *args, bus_time: bool = False) -> None:
        """Publish the latest signals if ``decide(*args, now)`` (the pacer) and they are new.

        The pacer runs on the bus's time base, as ``stale_mask`` does: ``now`` is the newest
        frame's bus time for a frame (``bus_time``), the wall clock mapped onto the bus for
        the timer. A bridge that falls behind (a busy PC) and then reads a backlog of frames
        in a burst therefore still publishes one sample per trigger frame, each with its
        trigger's stamp; paced by its own clock it held most of them back as "too fast".
        Runs on the receive thread (frames) and the executor (timer), hence the lock.
        """
        st = self.state
        assembler, pacer = st.assembler, st.pacer
        assert assembler is not None and pacer is not None  # configured
        with self._lock:
            newest = assembler.newest_time
            wall = self._node_time() if self._sim_time else time.time()
            now = newest if bus_time and newest is not None else wall - (st.offset or 0.0)
            if not decide(*args, now):
                return
            if newest is not None and st.offset is None:  # relative clocks -> the epoch
                skew = wall - newest
                st.offset = skew if abs(skew) > 3600.0 else 0.0
            if newest is None or not self._publish(assembler.snapshot()):
                pacer.refund()
                return
            # (st.offset was set above when it was None)
            st.lag_max = max(st.lag_max, wall - (st.offset or 0.0) - newest)

    def _publish(self, sample) -> bool:
        st = self.state
        if sample.stamp is None or sample.stamp == st.last_stamp or not st.active:
            return False
        st.last_stamp, st.last_new = sample.stamp, time.monotonic()
        st.stale_groups = sample.stale
        st.stale_samples += bool(sample.stale_mask)
        assert self._rig_pub is not None  # active, so configured
        self._rig_pub.publish(self._rig_encode(sample, sample.stamp + (st.offset or 0.0)))
        st.published += 1
        return True


def _frames(cols: Columns) -> list[RawFrame]:
    """Return every frame of ``cols`` as tuples (the Python path)."""
    return [frame_at(cols, i) for i in range(cols.stamp.size)]
