"""How a node process runs: ``--help`` without ROS, the executor, spin, clean shutdown.

Every node's ``main(args=None)`` calls :func:`run_node`, which answers ``--help`` without
starting ROS (listing every parameter with unit, range and default), spins the node and shuts
down cleanly on SIGINT / SIGTERM: exit 0, as ``ros2 launch`` expects of a node it stops.

How a signal stops a node: rclpy's own handlers (``SignalHandlerOptions.ALL``) wake the
executor and shut the context down from a thread of theirs, and the spin ends. rclpy's SIGINT
handler also chains to the handler it found, Python's, which raises ``KeyboardInterrupt`` in
the main thread at the next bytecode it runs, wherever that is; inside the Python code that
rclpy's C++ calls (the message class that ``Subscription.take_message`` builds) pybind11
turns that exception into ``RuntimeError: Unable to convert call argument '0' to Python
object``, often before rclpy's thread has shut the context down: exit 1 (about one
controller stop in seven, the controller taking three topics). So while a node runs, SIGINT
and SIGTERM reach Python only as a note (:class:`_StopSignals`), never as an exception; the
context shutdown is the one way a signal stops the node.
"""

from __future__ import annotations

import gc
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from clutch_ros.errors import ClutchError
from clutch_ros.nodes.diagnostics import Diagnostics
from clutch_ros.nodes.lean_executor import LeanExecutor
from clutch_ros.nodes.parameters import ParamSpec, format_help, help_requested
from clutch_ros.nodes.realtime import (
    REALTIME_PARAMS,
    RealtimeReport,
    apply_realtime,
    declare_realtime,
)

__all__ = ["DEFAULT_EXECUTOR", "EVENTS_WARNING", "executor_option", "make_executor", "run_node",
           "run_interruptibly", "run_nodes", "start_realtime"]


#: Executor the nodes spin by default: :class:`~clutch_ros.nodes.lean_executor.LeanExecutor`,
#: rclpy's SingleThreadedExecutor without its per-callback overhead (about half the CPU per
#: wake-up, ``python -m benchmarks.wakeup_probe``; figures in benchmarks/RESULTS.md).
#: ``--executor single`` (before ``--ros-args``) selects rclpy's own, ``--executor events``
#: rclpy.experimental.EventsExecutor (not usable with these wheels: :data:`EVENTS_WARNING`).
DEFAULT_EXECUTOR = "lean"


#: Logged when ``--executor events`` is chosen: what the EventsExecutor did here.
EVENTS_WARNING = ("--executor events is experimental: with the rclpy 9.1.2 wheels from PyPI "
                  "it ran no subscription or timer callbacks after the first spin and ignored "
                  "SIGINT; use the default (lean) or single unless your rclpy build was checked "
                  "with 'python -m benchmarks.estimator_node'")


def make_executor(kind: str = DEFAULT_EXECUTOR):
    """Return a new ``single``, ``lean`` or ``events`` executor.

    ``single``: rclpy's SingleThreadedExecutor; ``lean``: :mod:`lean_executor`; ``events``:
    rclpy's EventsExecutor.
    """
    if kind == "lean":
        return LeanExecutor()
    if kind == "events":
        from rclpy.experimental import EventsExecutor  # experimental: loaded only when chosen

        return EventsExecutor()
    if kind == "single":
        return SingleThreadedExecutor()
    raise ValueError(f"unknown executor {kind!r} (single, lean or events)")


def executor_option(argv: list[str]) -> tuple[str, list[str]]:
    """Take ``--executor KIND`` (before ``--ros-args``) out of ``argv``."""
    kind = DEFAULT_EXECUTOR
    out: list[str] = []
    it = iter(argv)
    for arg in it:
        if arg == "--ros-args":
            out.append(arg)
            out.extend(it)
            break
        if arg == "--executor":
            kind = next(it, DEFAULT_EXECUTOR)
        elif arg.startswith("--executor="):
            kind = arg.split("=", 1)[1]
        else:
            out.append(arg)
    return kind, out


class _StopSignals:
    """Python's SIGINT and SIGTERM handlers while a node runs: they note the signal, no more.

    rclpy's handlers, installed over these by ``rclpy.init``, call them (chained) and do the
    stopping; a signal that arrives before ``rclpy.init`` installed them is noted here
    (:attr:`received`) and stops the node as soon as it is built. Installed only in the main
    thread (the only one where Python allows it); :meth:`restore` puts the previous back.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: list[int] = []
        self._previous: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                self._previous[signum] = signal.signal(signum, self._note)

    def _note(self, signum: int, _frame: Any) -> None:
        self.received.append(signum)

    def restore(self) -> None:
        """Put back the handlers found at construction."""
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()


def run_node(name: str, doc: str, specs: Sequence[ParamSpec], factory: Callable[[], Node],
             args: Sequence[str] | None = None) -> int:
    """Answer --help, or init rclpy, build the node with ``factory`` and spin until shutdown.

    Bad settings (a ClutchError or rclpy ParameterException while building the node) print
    one line ``<name>: error: ...`` and return 2, never a traceback (0 when a signal stopped
    the start meanwhile: the error is then the stop's consequence).
    """
    argv = list(sys.argv[1:] if args is None else args)
    if help_requested(argv):
        sys.stdout.write(format_help(name, doc, [*specs, *REALTIME_PARAMS]))
        return 0
    executor_kind, argv = executor_option(argv)
    return run_nodes(name, [factory], argv, executor_kind)


def run_nodes(name: str, factories: Sequence[Callable[[], Node]], argv: Sequence[str],
              executor_kind: str = DEFAULT_EXECUTOR) -> int:
    """Init rclpy with ``argv``, build each node and spin them all in one executor.

    :func:`run_node` for one node; :mod:`clutch_ros.nodes.composed` for several in one
    process. Exit codes and the handling of signals and bad settings as :func:`run_node`;
    the nodes are closed and destroyed in reverse build order.
    """
    # rclpy's own handlers (SignalHandlerOptions.ALL, the default) turn SIGINT and SIGTERM
    # into a clean shutdown even while the executor waits in C; Python's only take note
    # (module docstring: a KeyboardInterrupt inside rclpy's C++ was an exit 1)
    stop = _StopSignals()
    rclpy.init(args=[sys.argv[0], *argv])
    nodes: list[Node] = []
    started = False
    try:
        if stop.received:  # stopped before rclpy's handlers were there to do it
            return 0
        # made while the context is surely valid: a node may end the context from its own
        # thread while it is being built (bag_player on a bad bag), and an executor made on
        # an ended context fails half-built (its __del__ then prints a traceback)
        executor = make_executor(executor_kind)
        for factory in factories:
            nodes.append(factory())
            if stop.received:  # (the context is shut down: nothing to spin)
                return 0
        realtime = [start_realtime(node) for node in nodes]
        started = True
        # everything built so far lives as long as the node: out of the collector's sight, so
        # a full collection (every ~10^5 allocations at 1 kHz) does not walk the imported
        # modules and the message classes in the middle of a callback (latency tail)
        gc.collect()
        gc.freeze()
        for node in nodes:
            if executor_kind == "events":
                node.get_logger().warning(EVENTS_WARNING)
            executor.add_node(node)
        executor.spin()
        del realtime  # its /diagnostics timers lived as long as the spin
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # rclpy raises RCLError (a RuntimeError) when a take, publish or timer meets the
        # context that a signal shut down meanwhile: the requested stop, not a failure
        if rclpy.ok():
            raise
    except (ClutchError, ParameterException, ValueError) as err:
        if not rclpy.ok():
            # a signal shut the context down while the node was being built (a lifecycle
            # node's autostart then fails to publish): the requested stop, not bad settings
            return 0
        if started:  # an error after start-up is a bug: show it
            raise
        sys.stderr.write(f"{name}: error: {err}\n")
        return 2
    finally:
        for node in reversed(nodes):
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
        # nothing is collected any more: out of the exit's last collection, which walked
        # numba's objects for ~0.6 s of CPU when a stop came before the gc.freeze above
        # (more than ros2 launch's 5 s beside busy processes); 0.17 s with this
        gc.freeze()
    return 0


def run_interruptibly(work: Callable[[], object], stopped: Callable[[], bool],
                      poll_s: float = 0.05) -> bool:
    """Run ``work`` in a daemon thread; return False if ``stopped()`` came true before it ended.

    For slow set-up while a node is built (the can_bridge's compiled intake: ~1 s to load
    from numba's cache on an idle machine, more than 5 s beside busy processes, measured:
    SIGINT during that load was answered after ``ros2 launch``'s 5 s). Nothing can interrupt
    an import, so the calling thread checks ``stopped()`` every ``poll_s`` [s] beside it (a
    node passes ``lambda: not self.context.ok()``: a stop signal shuts the context down) and
    gives up at once; the unfinished daemon thread ends with the process. An exception of
    ``work`` is raised here.
    """
    done = threading.Event()
    failure: list[BaseException] = []

    def target() -> None:
        try:
            work()
        except BaseException as err:  # noqa: BLE001 - handed to the main thread
            failure.append(err)
        finally:
            done.set()

    threading.Thread(target=target, name="slow_load", daemon=True).start()
    while not done.wait(poll_s):  # (signal handlers run between the waits)
        if stopped():
            return False
    if failure:
        raise failure[0]
    return True


def start_realtime(node) -> Diagnostics | None:
    """Declare the node's ``rt.*`` parameters, apply them, report (ValueError if invalid).

    Returns the ``<node>/realtime`` status publisher when an option was requested (keep it as
    long as the node spins), else None.
    """
    settings = declare_realtime(node)  # every node's rt.* parameters (nodes/realtime.py)
    return _report_realtime(node, apply_realtime(settings)) if settings.requested else None


def _report_realtime(node, report: RealtimeReport) -> Diagnostics:
    """Log what the real-time options did and publish it as ``<node>/realtime`` (every 5 s)."""
    line = report.message()
    if report.refused:
        node.get_logger().warning(line)
    else:
        node.get_logger().info(line)
    values = {"applied": ", ".join(report.applied), "refused": "; ".join(report.refused)}
    return Diagnostics(node, lambda: (report.level, line, values), period_s=5.0,
                       suffix="/realtime")
