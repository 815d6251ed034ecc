"""A single-threaded executor that does less per wake-up than rclpy's own: the nodes' default.

:func:`clutch_ros.nodes.runner.make_executor` ``"lean"``; ``--executor single`` (before
``--ros-args``) runs a node on rclpy's SingleThreadedExecutor instead.

rclpy 9's :class:`~rclpy.executors.SingleThreadedExecutor` pays, for every callback, work that
is not the callback: it gathers every entity of every node into a new wait set (each
parameter service, lifecycle service, timer, QoS event handler, guard condition), wraps the
callback in a :class:`~rclpy.task.Task` whose handler triggers the executor's guard condition
twice, so the next wait returns at once for nothing and the wait set is built a second time;
and on every timer call it inspects the callback's signature (``inspect.signature``).
``python -m benchmarks.wakeup_probe`` measures these costs per message.

:class:`LeanExecutor` keeps the semantics for the entities the nodes use and drops that
overhead on the hot path:

* the entity lists and the wait set are built once and rebuilt only when the executor's guard
  condition fired (rclpy triggers it whenever a node adds or destroys an entity, or a node is
  added or removed); each wait re-adds the handles to the kept wait set;
* a ready subscription's message is taken and its callback called directly; a ready timer is
  called directly (whether the callback takes a ``TimerInfo`` is looked up once per callback);
* services, clients, node guard conditions and waitables (QoS event handlers) go through
  rclpy's own task machinery (they are rare); while such a task is still pending (a coroutine
  callback), iterations are rclpy's;
* QoS event handlers (incompatible QoS, deadline, liveliness: about ten per node, each added
  to the wait set and asked whether it is ready, ~5 % of a wake-up) join the wait at most every
  :data:`EVENT_POLL_PERIOD`: an event stays pending in the middleware until it is taken, so it
  is handled at most that much later, and an idle node still looks at least that often (the
  wait is bounded by the next poll while handlers are left out).

Exceptions of callbacks propagate out of :meth:`spin_once` as with rclpy's executor; a context
shut down (a signal) raises :class:`~rclpy.executors.ExternalShutdownException`.

A signal: rclpy's signal thread first triggers every executor's SIGINT guard condition, then
shuts the contexts down (rclpy's ``signal_handler.cpp``). A wait woken by the trigger can see
the context still valid and wait again, with no timeout when nothing else is due: a node with
no timer then never stops (bag_player, SIGTERM beside two busy processes: 4 of 30 stops hung
until SIGKILL). So a wake-up by that guard condition waits, at most
:data:`SIGNAL_SHUTDOWN_WAIT`, for the shutdown that follows it and ends the spin.
"""

from __future__ import annotations

import inspect
import time
from contextlib import ExitStack
from functools import partial
from typing import Any, cast

from rclpy.event_handler import EventHandler
from rclpy.exceptions import InvalidHandle
from rclpy.executors import (
    ExternalShutdownException,
    SingleThreadedExecutor,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription
from rclpy.timer import TimerInfo
from rclpy.utilities import timeout_sec_to_nsec

__all__ = ["EVENT_POLL_PERIOD", "SIGNAL_SHUTDOWN_WAIT", "LeanExecutor"]

#: [s] how often QoS event handlers join the wait (module docstring)
EVENT_POLL_PERIOD = 0.5
#: [s] wall: after a signal's guard condition, at most this for the context's shutdown
SIGNAL_SHUTDOWN_WAIT = 2.0


def _timer_info_arg(callback) -> str | None:
    """Name of the parameter of ``callback`` annotated ``TimerInfo``, or None (as rclpy)."""
    try:
        params = inspect.signature(callback).parameters.values()
    except (TypeError, ValueError):
        return None
    return next((p.name for p in params if p.annotation == TimerInfo), None)


class LeanExecutor(SingleThreadedExecutor):
    """SingleThreadedExecutor with a kept wait set and direct calls (see module docstring)."""

    def __init__(self, *, context=None) -> None:
        super().__init__(context=context)
        self._held: ExitStack | None = None  # the handles in use while the wait set is kept
        self._wait_set: Any = None
        self._subs: list = []
        self._timers: list = []
        self._others: list = []  # (entity, node, take) for services, clients, guards
        self._waitables: list = []  # (waitable, node), but QoS event handlers
        self._events: list = []  # (QoS event handler, node): polled (EVENT_POLL_PERIOD)
        self._events_due = 0.0  # [s] time.monotonic() when they next join the wait
        self._handles: tuple[list, list, list, list, list] = ([], [], [], [], [])
        self._timer_args: dict[int, tuple[Any, str | None]] = {}
        self.rebuilds = 0  # how often the wait set was built (a probe reads it)

    # -- wait set ----------------------------------------------------------------------------
    def _release(self) -> None:
        if self._held is not None:
            self._held.close()
        self._held, self._wait_set = None, None

    def _build(self) -> None:
        """Gather every entity of every node, enter their handles, size a new wait set."""
        self._release()
        self.rebuilds += 1
        stack = ExitStack()
        subs: list[Any] = []
        timers: list[Any] = []
        others: list[Any] = []
        waitables: list[Any] = []
        sub_h: list[Any] = []
        tmr_h: list[Any] = []
        cli_h: list[Any] = []
        srv_h: list[Any] = []
        gc_h: list[Any] = []
        n_events = 0
        extra: dict[str, int] = {}

        def enter(entity, handles) -> bool:
            try:
                stack.enter_context(entity.handle)
            except InvalidHandle:
                return False
            handles.append(entity.handle)
            return True

        for node in self.get_nodes():
            subs += [s for s in node.subscriptions if enter(s, sub_h)]
            timers += [t for t in node.timers if enter(t, tmr_h)]
            others += [(c, node, self._take_client) for c in node.clients if enter(c, cli_h)]
            others += [(s, node, self._take_service) for s in node.services if enter(s, srv_h)]
            others += [(g, node, self._take_guard_condition) for g in node.guards
                       if enter(g, gc_h)]
            for wt in node.waitables:
                try:
                    stack.enter_context(wt)
                except InvalidHandle:
                    continue
                waitables.append((wt, node))
                counts = wt.get_num_entities()
                n_events += counts.num_events
                for key in ("subscriptions", "guard_conditions", "timers", "clients",
                            "services"):
                    extra[key] = extra.get(key, 0) + getattr(counts, f"num_{key}")
        for gc in (self._guard, self._sigint_gc):
            if gc is not None:
                stack.enter_context(gc.handle)
                gc_h.append(gc.handle)
        context: Any = self._context.handle
        stack.enter_context(context)
        self._wait_set = _rclpy.WaitSet(
            len(sub_h) + extra.get("subscriptions", 0),
            len(gc_h) + extra.get("guard_conditions", 0), len(tmr_h) + extra.get("timers", 0),
            len(cli_h) + extra.get("clients", 0), len(srv_h) + extra.get("services", 0),
            n_events, context)
        self._held = stack
        self._subs, self._timers, self._others = subs, timers, others
        self._waitables = [(wt, n) for wt, n in waitables if not isinstance(wt, EventHandler)]
        self._events = [(wt, n) for wt, n in waitables if isinstance(wt, EventHandler)]
        self._handles = (sub_h, tmr_h, cli_h, srv_h, gc_h)

    # -- spinning ----------------------------------------------------------------------------
    def spin(self) -> None:
        """Execute callbacks until shutdown (the handles are released at the end)."""
        try:
            while self._context.ok() and not self._is_shutdown:
                self._lean_once(None)
        finally:
            self._release()

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to ``timeout_sec`` [s] (None: forever) and run what is ready."""
        try:
            self._lean_once(timeout_sec)
        finally:
            self._release()

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Shut down as rclpy's executor.

        The kept handles are released by the spin that holds them, when it ends (this wakes
        it), never here: shutdown may come from another thread while that spin waits on them.
        """
        return super().shutdown(timeout_sec)

    def _fill(self, ws, events: bool = True) -> None:
        """Clear the kept wait set and add every kept handle and waitable to it.

        ``events``: the QoS event handlers too.
        """
        sub_h, tmr_h, cli_h, srv_h, gc_h = self._handles
        ws.clear_entities()
        for h in sub_h:
            ws.add_subscription(h)
        for h in cli_h:
            ws.add_client(h)
        for h in srv_h:
            ws.add_service(h)
        for h in tmr_h:
            ws.add_timer(h)
        for h in gc_h:
            ws.add_guard_condition(h)
        for wt, _node in self._waitables:
            wt.add_to_wait_set(ws)
        if events:
            for wt, _node in self._events:
                wt.add_to_wait_set(ws)

    def _lean_once(self, timeout_sec: float | None) -> None:
        if self._tasks:  # a coroutine callback is pending: rclpy's iteration runs tasks
            self._release()
            super().spin_once(timeout_sec)
            return
        if self._wait_set is None:
            self._build()
        now = time.monotonic()
        events = now >= self._events_due
        if events:
            self._events_due = now + EVENT_POLL_PERIOD
        try:
            self._fill(self._wait_set, events)
        except InvalidHandle:
            # an entity destroyed by a callback of the last iteration (a lifecycle cleanup
            # destroys publishers and their QoS event handlers from a service callback): the
            # guard condition that says so is only seen by the next wait, so rebuild now
            self._build()
            self._fill(self._wait_set, events)
        ws = self._wait_set
        if not events and self._events:  # left out: wake for them by the next poll at least
            due = self._events_due - now
            timeout_sec = due if timeout_sec is None or timeout_sec < 0 else min(timeout_sec, due)
        ws.wait(timeout_sec_to_nsec(timeout_sec))
        if self._is_shutdown:
            return
        if not self._context.ok():
            raise ExternalShutdownException()
        guards_ready = ws.get_ready_entities("guard_condition")
        if self._sigint_gc is not None and self._sigint_gc.handle.pointer in guards_ready:
            self._signalled()
        if self._guard is not None and self._guard.handle.pointer in guards_ready:
            self._wait_set = None  # entities changed (or a task was made): rebuild next time
        for gc, _node, _take in self._others:
            if getattr(gc, "_executor_triggered", None) is not None \
                    and gc.handle.pointer in guards_ready:
                gc._executor_triggered = True
        ready_waitables = [(wt, node) for wt, node in self._waitables if wt.is_ready(ws)]
        if events:
            ready_waitables += [(wt, node) for wt, node in self._events if wt.is_ready(ws)]
        timers_ready = ws.get_ready_entities("timer")
        subs_ready = ws.get_ready_entities("subscription")
        clients_ready = ws.get_ready_entities("client")
        services_ready = ws.get_ready_entities("service")
        for wt, node in ready_waitables:
            self._run_task(wt, node, self._take_waitable)
        for tmr in self._timers:
            if tmr.handle.pointer in timers_ready:
                self._call_timer(tmr)
        for sub in self._subs:
            if sub.handle.pointer in subs_ready:
                self._call_subscription(sub)
        for entity, node, take in self._others:
            if take == self._take_guard_condition:
                ready = getattr(entity, "_executor_triggered", False)
            else:
                ready = entity.handle.pointer in (
                    clients_ready if take == self._take_client else services_ready)
            if ready:
                self._run_task(entity, node, take)

    def _signalled(self) -> None:
        """Stop after a signal woke the wait, once rclpy's signal thread shut the context down.

        Raises ExternalShutdownException once the context is shut down, or after
        :data:`SIGNAL_SHUTDOWN_WAIT` regardless (the runner then shuts it down itself).
        """
        end = time.monotonic() + SIGNAL_SHUTDOWN_WAIT
        while self._context.ok() and time.monotonic() < end:
            time.sleep(0.001)
        raise ExternalShutdownException()

    def _call_subscription(self, sub) -> None:
        try:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
        except InvalidHandle:  # destroyed by an earlier callback of this iteration
            return
        if taken is None:
            return
        if sub._callback_type is Subscription.CallbackType.MessageOnly:
            result = sub.callback(taken[0])
        else:
            result = sub.callback(*taken)
        if inspect.iscoroutine(result):
            self.create_task(cast(Any, result))

    def _call_timer(self, tmr) -> None:
        try:
            with tmr.handle:
                if not tmr.handle.is_timer_ready():  # cancelled meanwhile (as rclpy checks)
                    return
                info = tmr.handle.call_timer_with_info()
        except Exception:  # noqa: BLE001 - InvalidHandle, TimerCancelledError: nothing to run
            return
        callback = tmr.callback
        if callback is None:
            return
        cached = self._timer_args.get(id(tmr))
        if cached is None or cached[0] is not callback:
            cached = (callback, _timer_info_arg(callback))
            self._timer_args[id(tmr)] = cached
        if cached[1] is not None:
            callback = partial(callback, **{cached[1]: TimerInfo(
                expected_call_time=info["expected_call_time"],
                actual_call_time=info["actual_call_time"], clock_type=tmr.clock.clock_type)})
        result = callback()
        if inspect.iscoroutine(result):
            self.create_task(cast(Any, result))

    def _run_task(self, entity, node, take) -> None:
        """Run a rare entity's callback through rclpy's task machinery, as its executor does."""
        handler = self._make_handler(entity, node, take)
        handler()
        if handler.done():
            with self._tasks_lock:
                self._tasks = [t for t in self._tasks if t[0] is not handler]
            handler.result()  # raise the callback's exception, as rclpy's executor does
