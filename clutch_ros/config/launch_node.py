"""The ``<node>`` element of an XML launch file: what ``ros2 launch`` would start, and how.

Read by :mod:`clutch_ros.config.launch_file`. The command line follows launch_ros's Node:
``EXEC [args] [--ros-args ROS_ARGS] --ros-args [-r __node:=NAME] [-r __ns:=NS]`` then the
parameters in document order, then the remappings. Like ``ros2 launch``, each
``<param name= value=>`` becomes a parameter file of its own (``--params-file``) whose section
is the node's full name (``/**`` when name or namespace is not set), and ``<param from=>`` is
passed as it is. The order and the section names matter: rcl keeps one parameter table per
section, in the order the sections first appear, and rclpy applies the matching tables in that
order; so a ``-p name:=value`` (a ``/**`` entry) would not give what ``ros2 launch`` gives.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from clutch_ros.config.errors import LaunchFileError
from clutch_ros.config.launch_subst import (
    Where,
    check_attrs,
    substitute,
    truth,
    typed_value,
)
from clutch_ros.config.params_file import flatten, load_yaml

__all__ = ["LaunchArg", "NodeEntry", "absolute_namespace", "node_entry", "prefix_namespace"]

NODE_ATTRS = {"pkg", "exec", "name", "namespace", "output", "args", "ros_args", "respawn",
              "respawn_delay", "respawn_max_retries"}
LITERAL_ATTRS = ("respawn_delay", "respawn_max_retries")  # numbers in launch, no substitutions


@dataclass(frozen=True)
class LaunchArg:
    """A declared ``<arg>``: its name, default (None: required) and description."""

    name: str
    default: str | None
    description: str = ""


@dataclass
class NodeEntry:
    """One ``<node>`` with every substitution resolved.

    ``namespace`` is None when neither the node nor an enclosing ``push-ros-namespace`` sets
    one (no ``__ns`` remapping: the node's own default, the root). ``parameter_args`` holds
    ``("file", path)`` and ``("values", [(name, value), ...])`` (one ``<param>``) in
    document order.
    """

    pkg: str
    executable: str
    name: str | None = None
    namespace: str | None = None
    arguments: list[str] = field(default_factory=list)
    ros_arguments: list[str] = field(default_factory=list)
    parameter_args: list[tuple] = field(default_factory=list)
    remaps: list[tuple[str, str]] = field(default_factory=list)
    respawn: bool = False
    respawn_delay: float = 0.0  # [s]
    respawn_max_retries: int = -1  # -1: no limit

    @property
    def full_name(self) -> str:
        """Return the fully qualified node name (``/rig1/estimator``)."""
        return f"{(self.namespace or '/').rstrip('/')}/{self.name or self.executable}"

    @property
    def params(self) -> list[tuple[str, Any]]:
        """Return the single parameters (name, typed value) in document order."""
        return [pair for item in self.parameter_args if item[0] == "values" for pair in item[1]]

    @property
    def param_files(self) -> list[str]:
        """Return the parameter files in document order."""
        return [p[1] for p in self.parameter_args if p[0] == "file"]

    @property
    def section(self) -> str:
        """Return the section ``ros2 launch`` writes this node's ``<param>`` values under."""
        return self.full_name if None not in (self.name, self.namespace) else "/**"

    def ros_args(self, param_dir: Path) -> list[str]:
        """Return the node's arguments (after the executable), as ``ros2 launch`` gives them.

        Writes the parameter file of each ``<param>`` into ``param_dir``.
        """
        args = list(self.arguments)
        if self.ros_arguments:
            args += ["--ros-args", *self.ros_arguments]
        args.append("--ros-args")
        if self.name is not None:
            args += ["-r", f"__node:={self.name}"]
        if self.namespace is not None:
            args += ["-r", f"__ns:={self.namespace}"]
        stem = self.full_name.strip("/").replace("/", ".")
        for index, item in enumerate(self.parameter_args, start=1):
            path = item[1]
            if item[0] == "values":
                path = Path(param_dir) / f"{stem}.{index}.yaml"
                path.parent.mkdir(parents=True, exist_ok=True)
                body = {self.section: {"ros__parameters": dict(item[1])}}
                path.write_text(yaml.safe_dump(body, default_flow_style=False))
            args += ["--params-file", str(path)]
        for src, dst in self.remaps:
            args += ["-r", f"{src}:={dst}"]
        return args

    def parameters(self) -> dict[str, Any]:
        """Return the parameters the node starts with, as rcl and rclpy resolve them.

        One table per section (``/**``, ``/**/name``, the full name ...) that matches the
        node, in the order the sections first appear; later entries of a table win, and the
        tables are applied in that order.
        """
        tables: dict[str, dict[str, Any]] = {}
        for item in self.parameter_args:
            if item[0] == "values":
                tables.setdefault(self.section, {}).update(item[1])
                continue
            data = load_yaml(item[1], "parameter file")
            if not isinstance(data, dict):
                raise LaunchFileError(f"{item[1]}: not a ROS 2 parameter file")
            for key, body in data.items():
                if _section_matches(str(key), self.full_name):
                    params = (body or {}).get("ros__parameters", {})
                    tables.setdefault(str(key), {}).update(flatten(params, source=item[1]))
        out: dict[str, Any] = {}
        for table in tables.values():
            out.update(table)
        return out


def _section_matches(section: str, full_name: str) -> bool:
    """Match a section as rcl does: ``/**`` any namespaces, ``*`` one name, relative: never."""
    if not section.startswith("/"):
        return False
    pattern = "".join("(/[^/]+)*" if part == "**" else "/" + re.escape(part).replace(
        r"\*", "[^/]+") for part in section.strip("/").split("/"))
    return re.fullmatch(pattern, full_name) is not None


def prefix_namespace(base: str | None, ns: str | None) -> str | None:
    """Combine a pushed namespace and a node's namespace as launch_ros does."""
    if ns is None:
        combined = base
    elif not base or ns.startswith("/"):
        combined = ns
    else:
        combined = ("" if base == "/" else base) + "/" + ns
    if combined is not None and combined != "/":
        combined = combined.rstrip("/")
    return combined


def absolute_namespace(ns: str | None) -> str | None:
    """Return ``ns`` with a leading ``/`` (None stays None)."""
    return ns if ns is None or ns.startswith("/") else "/" + ns


def node_entry(elem, where: Where, variables: dict[str, str], pushed_ns: str | None) -> NodeEntry:
    """Return the :class:`NodeEntry` of ``<node>`` element ``elem`` in the current scope."""
    check_attrs(elem, where, NODE_ATTRS, {"exec"})
    sub = {k: substitute(v, variables, where) for k, v in elem.attrib.items()
           if k not in ("if", "unless", *LITERAL_ATTRS)}
    for k in LITERAL_ATTRS:
        if k in elem.attrib:
            if "$(" in elem.attrib[k]:
                raise LaunchFileError(f"{where}: {k} takes a plain number (ros2 launch does "
                                      "not substitute it)")
            sub[k] = elem.attrib[k]
    if "pkg" not in sub:
        raise LaunchFileError(f"{where}: nodes without pkg= cannot be started here")
    entry = NodeEntry(sub["pkg"], sub["exec"], sub.get("name"))
    entry.namespace = absolute_namespace(prefix_namespace(pushed_ns, sub.get("namespace")))
    entry.arguments = sub.get("args", "").split()
    entry.ros_arguments = sub.get("ros_args", "").split()
    entry.respawn = truth(sub.get("respawn", "false"), where, "respawn")
    try:
        entry.respawn_delay = float(sub.get("respawn_delay", "0"))
        entry.respawn_max_retries = int(sub.get("respawn_max_retries", "-1"))
    except ValueError as err:
        raise LaunchFileError(f"{where}: {err}") from None
    if entry.respawn_delay < 0.0:
        raise LaunchFileError(f"{where}: respawn_delay must not be negative")
    for child in elem.children:
        cwhere = Where(where.file, child.line, child.tag)
        if child.tag == "param" and "from" in child.attrib:
            check_attrs(child, cwhere, {"from"}, {"from"})
            entry.parameter_args.append(("file", substitute(child.attrib["from"], variables,
                                                            cwhere)))
        elif child.tag == "param":
            entry.parameter_args.append(("values", _params(child, cwhere, variables, "")))
        elif child.tag == "remap":
            check_attrs(child, cwhere, {"from", "to"}, {"from", "to"})
            entry.remaps.append((substitute(child.attrib["from"], variables, cwhere),
                                 substitute(child.attrib["to"], variables, cwhere)))
        else:
            raise LaunchFileError(f"{cwhere}: unsupported element inside <node> (supported: "
                                  "param, remap)")
        if {"if", "unless"} & set(child.attrib):
            raise LaunchFileError(f"{cwhere}: if/unless are not supported here")
    return entry


def _params(elem, where: Where, variables, prefix: str) -> list[tuple[str, Any]]:
    """Return ``(dotted name, typed value)`` of a ``<param>`` (nested ones flattened)."""
    check_attrs(elem, where, {"name", "value", "type"}, {"name"})
    name = prefix + substitute(elem.attrib["name"], variables, where)
    if elem.children:
        if {"value", "type"} & set(elem.attrib):
            raise LaunchFileError(f"{where}: parameter {name}: value/type and nested <param> "
                                  "are mutually exclusive")
        out = []
        for child in elem.children:
            cwhere = Where(where.file, child.line, child.tag)
            if child.tag != "param":
                raise LaunchFileError(f"{cwhere}: unsupported element inside <param>")
            out += _params(child, cwhere, variables, name + ".")
        return out
    if "value" not in elem.attrib:
        raise LaunchFileError(f"{where}: parameter {name} needs value= or nested <param>")
    text = substitute(elem.attrib["value"], variables, where)
    return [(name, typed_value(text, elem.attrib.get("type"), where, name))]
