"""Parameter names as the dashboard shows them, and the read-only set of a bag's playback.

A parameter is named ``<node>.<parameter>``, the node's fully qualified name first (as
foxglove_bridge names them): ``/estimator.spline.law``, ``/rig1/controller.controller.rate``.
ROS node names contain no dot, so the first dot after the last ``/`` splits the two
(:func:`split_name`).

:class:`ReadOnlyParameters` serves ``clutch dashboard --bag``: the estimator parameters the
estimates were computed with, shown under ``/estimator.``; every set is refused with the reason
(the estimates of the whole bag were computed before playback started).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from clutch_ros.dashboard.errors import DashboardError

__all__ = ["ReadOnlyParameters", "full_name", "split_name"]


def full_name(node: str, parameter: str) -> str:
    """``/estimator`` and ``spline.law`` -> ``/estimator.spline.law``."""
    return f"{node}.{parameter}"


def split_name(name: str) -> tuple[str, str]:
    """``/estimator.spline.law`` -> (``/estimator``, ``spline.law``).

    Raises:
        DashboardError: ``name`` is not ``/node.parameter``.

    """
    slash = name.rfind("/")
    dot = name.find(".", slash + 1)
    if not name.startswith("/") or dot <= slash + 1 or dot == len(name) - 1:
        raise DashboardError(f"parameter name {name!r} is not /node.parameter "
                             "(e.g. /estimator.spline.law)")
    return name[:dot], name[dot + 1:]


class ReadOnlyParameters:
    """A fixed set of one node's parameters that refuses every change.

    Args:
        node: fully qualified node name the parameters are shown under (``/estimator``).
        values: parameter name -> value (``ClutchParams.to_flat()``).
        reason: why they cannot be set (shown to the client).

    """

    def __init__(self, node: str, values: Mapping[str, Any], reason: str):
        self._values = {full_name(node, k): _plain(v) for k, v in values.items()}
        self.reason = reason

    def get(self, names: list[str]) -> dict[str, Any]:
        """Return name -> value of ``names`` known here (empty: all of them)."""
        if not names:
            return dict(self._values)
        return {n: self._values[n] for n in names if n in self._values}

    def set(self, changes: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
        """Refuse every change; return the values in force and one reason per name."""
        refusals = [f"{name}: read-only: {self.reason}" if name in self._values else
                    f"{name}: no such parameter" for name in changes]
        return self.get([n for n in changes if n in self._values]), refusals


def _plain(value: Any) -> Any:
    """Numpy scalars and tuples as plain Python values."""
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value
