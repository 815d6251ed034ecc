"""The dashboard node's parameters capability: the clutch nodes' parameters, by their services.

:class:`RosParameters` lists, gets and sets the parameters of the clutch nodes in the
dashboard's namespace through each node's own ROS parameter services (``rcl_interfaces``:
``~/list_parameters``, ``~/get_parameters``, ``~/set_parameters``), so the node's validation
(ranges in its descriptors, read-only parameters, its own callback) decides and its reason for
a refusal is what the client sees. Names are ``<node>.<parameter>``
(:mod:`clutch_ros.dashboard.parameters`). The foxglove-sdk calls :meth:`get`/:meth:`set` on
its own threads; they wait (at most ``timeout`` per call) for the answers the node's executor
delivers, so the executor must spin in another thread (it does: ``run_node``). Changes made
by anyone (``ros2 param set`` too) reach subscribed clients from ``/parameter_events``.
"""

from __future__ import annotations

import threading
from typing import Any

from rcl_interfaces.msg import ParameterEvent, ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.parameter import Parameter, parameter_value_to_python

from clutch_ros.dashboard.errors import DashboardError
from clutch_ros.dashboard.parameters import full_name, split_name

__all__ = ["CLUTCH_NODES", "RosParameters"]

#: The nodes whose parameters the dashboard shows (in its own namespace).
CLUTCH_NODES = ("estimator", "controller", "can_bridge", "rig_sim", "recorder", "bag_player")
_SERVICES = {"list": ListParameters, "get": GetParameters, "set": SetParameters}


def _coerce(value: Any, like: Any) -> Any:
    """``value`` in the type of the current value ``like`` when that loses nothing."""
    if isinstance(like, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(like, int) and not isinstance(like, bool) and isinstance(value, float) \
            and value.is_integer():
        return int(value)
    if isinstance(like, list) and like and isinstance(like[0], float) and isinstance(value, list):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    return value


def _python(msg_value: Any) -> Any:
    value: Any = parameter_value_to_python(msg_value)
    if hasattr(value, "tolist"):  # array.array of the array types
        value = value.tolist()
    return list(value) if isinstance(value, tuple) else value


class RosParameters:
    """Parameters of the clutch nodes through their parameter services.

    Args:
        node: the dashboard node (creates the service clients in its executor thread).
        on_change: called with ``{full name: value}`` on every parameter event of a node.
        names: node names to serve (default :data:`CLUTCH_NODES`).
        timeout: wait for one service answer [s].

    """

    def __init__(self, node: Any, on_change, names=CLUTCH_NODES, timeout: float = 2.0):
        self._node = node
        self._names = tuple(names)
        self._timeout = float(timeout)
        self._on_change = on_change
        self._lock = threading.Lock()
        self._clients: dict[str, dict[str, Any]] = {}
        ns = node.get_namespace()
        self._prefix = "" if ns == "/" else ns
        node.create_subscription(ParameterEvent, "/parameter_events", self._on_event, 100)
        node.create_timer(1.0, self.discover)
        self.discover()

    def discover(self) -> None:
        """Create service clients for clutch nodes that appeared (executor thread)."""
        ns = self._node.get_namespace()
        for name, namespace in self._node.get_node_names_and_namespaces():
            fq = f"{self._prefix}/{name}"
            if name in self._names and namespace == ns and fq not in self._clients:
                clients = {kind: self._node.create_client(srv, f"{fq}/{kind}_parameters")
                           for kind, srv in _SERVICES.items()}
                with self._lock:
                    self._clients[fq] = clients

    def nodes(self) -> list[str]:
        """Return the fully qualified names of the nodes found so far."""
        with self._lock:
            return sorted(self._clients)

    # -- the handler interface of the dashboard server ----------------------------------------
    def get(self, names: list[str]) -> dict[str, Any]:
        """Return full name -> value of ``names`` (empty: every parameter of every node)."""
        wanted = self._by_node(names) if names else {fq: [] for fq in self.nodes()}
        values: dict[str, Any] = {}
        for fq, params in wanted.items():
            if fq not in self._clients:
                continue
            if not params:
                answer = self._call(fq, "list", ListParameters.Request())
                params = list(answer.result.names)
            values.update(self._get(fq, params))
        return values

    def set(self, changes: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
        """Set ``changes`` node by node; return the values in force and the refusals."""
        refusals: list[str] = []
        values: dict[str, Any] = {}
        for fq, params in self._by_node(list(changes)).items():
            if fq not in self._clients:
                refusals.extend(f"{full_name(fq, p)}: no node {fq} (the dashboard reaches: "
                                f"{', '.join(self.nodes()) or 'none yet'})" for p in params)
                continue
            current = self._get(fq, params)
            request = SetParameters.Request()
            for p in params:
                value = _coerce(changes[full_name(fq, p)], current.get(full_name(fq, p)))
                try:
                    request.parameters.append(Parameter(p, value=value).to_parameter_msg())
                except (TypeError, ValueError) as err:
                    refusals.append(f"{full_name(fq, p)}: {value!r} is no parameter value: {err}")
            answer = self._call(fq, "set", request) if request.parameters else None
            for msg, result in zip(request.parameters, answer.results if answer else []):
                if not result.successful:
                    refusals.append(f"{full_name(fq, msg.name)}: {result.reason}")
            values.update(self._get(fq, params))
        return values, refusals

    # -- helpers --------------------------------------------------------------------------------
    def _by_node(self, names: list[str]) -> dict[str, list[str]]:
        grouped: dict[str, list[str]] = {}
        for name in names:
            fq, param = split_name(name)
            grouped.setdefault(fq, []).append(param)
        return grouped

    def _get(self, fq: str, params: list[str]) -> dict[str, Any]:
        if not params:
            return {}
        answer = self._call(fq, "get", GetParameters.Request(names=params))
        return {full_name(fq, p): _python(v) for p, v in zip(params, answer.values)
                if v.type != ParameterType.PARAMETER_NOT_SET}

    def _call(self, fq: str, kind: str, request: Any) -> Any:
        with self._lock:
            client = self._clients[fq][kind]
        done = threading.Event()
        if not client.service_is_ready():
            raise DashboardError(f"{client.srv_name} is not available")
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(self._timeout) or future.result() is None:
            client.remove_pending_request(future)
            raise DashboardError(f"{client.srv_name} did not answer within {self._timeout:g} s")
        return future.result()

    def _on_event(self, event: Any) -> None:
        fq = event.node
        with self._lock:
            known = fq in self._clients
        if not known:
            return
        changed = {full_name(fq, p.name): _python(p.value)
                   for p in (*event.new_parameters, *event.changed_parameters)}
        if changed:
            self._on_change(changed)
