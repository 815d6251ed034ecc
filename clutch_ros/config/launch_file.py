"""Read ROS 2 XML launch files as ``ros2 launch`` does, for the node set ``clutch up`` starts.

``ros2 launch`` (launch, launch_ros, launch_xml) is not on the package index, so
``clutch up`` starts the nodes of a launch file itself from what this module reads. Only
elements, attributes and substitutions that launch_xml defines are accepted, with the same
meaning; anything else is a :class:`LaunchFileError` naming file, line and element (never
silently ignored). Substitutions and value types: :mod:`clutch_ros.config.launch_subst`.

Every element takes ``if=``/``unless=``. Elements:

- ``<launch>``: the root.
- ``<arg name= [default=] [description=]/>``: declare an argument. It keeps a value already
  set (``name:=value`` on the command line, an ``<include>``'s ``<arg>``, an earlier
  ``<let>``), else takes its default; without either it is an error.
- ``<let name= value=/>``: set a launch configuration.
- ``<group [scoped=]>``: its children; scoped (the default) means configurations and the ROS
  namespace set inside are forgotten at its end. ``forwarding="false"`` is refused.
- ``<push-ros-namespace namespace=/>`` (or ``push_ros_namespace``): prefix the namespace of the
  following nodes of the scope; a relative node namespace is appended to it, an absolute one
  (``/x``, ``/``) is kept as it is.
- ``<include file=>`` with ``<arg name= value=/>`` children: read another XML launch file in
  the same scope (not a group: its ``<let>``/``<arg>`` values stay set afterwards). A relative
  ``file`` is relative to the working directory, as in ``ros2 launch``; use ``$(dirname)``.
- ``<node pkg= exec= [name=] [namespace=] [args=] [ros_args=] [respawn=] [respawn_delay=]
  [respawn_max_retries=] [output=]>`` with ``<param name= value= [type=]/>``, nested
  ``<param name=><param .../></param>``, ``<param from=/>`` (a parameter file) and
  ``<remap from= to=/>`` children. Parameters keep document order and reach the node as with
  ``ros2 launch`` (:mod:`clutch_ros.config.launch_node`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

from clutch_ros.config.errors import LaunchFileError  # re-exported: its old home
from clutch_ros.config.launch_node import (
    LaunchArg,
    NodeEntry,
    absolute_namespace,
    node_entry,
    prefix_namespace,
)
from clutch_ros.config.launch_subst import Where, check_attrs, package_share, substitute, truth

__all__ = ["LaunchArg", "LaunchDescription", "LaunchFileError", "NodeEntry", "load_launch",
           "package_share", "parse_overrides"]

MAX_INCLUDE_DEPTH = 20


@dataclass
class Element:
    """One XML element with the line it starts on."""

    tag: str
    attrib: dict[str, str]
    line: int
    children: list[Element] = field(default_factory=list)


@dataclass
class LaunchDescription:
    """What a launch file starts: its declared arguments, the values used, the nodes."""

    path: Path
    args: list[LaunchArg]
    values: dict[str, str]
    nodes: list[NodeEntry]


@dataclass
class _Scope:
    variables: dict[str, str]
    namespace: str | None = None

    def copy(self) -> _Scope:
        return _Scope(dict(self.variables), self.namespace)


def parse_overrides(items: list[str]) -> dict[str, str]:
    """Parse command-line ``name:=value`` items into a mapping."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name or not re.fullmatch(r"[A-Za-z_][\w.-]*", name):
            raise LaunchFileError(f"launch argument {item!r} is not name:=value")
        out[name] = value
    return out


def read_xml(path: Path) -> Element:
    """Parse ``path`` into :class:`Element` objects that know their line numbers."""
    if path.suffix in (".py", ".yaml", ".yml"):
        raise LaunchFileError(f"{path}: only XML launch files can be read here (not "
                              f"{path.suffix})")
    parser = expat.ParserCreate()
    stack: list[Element] = []
    roots: list[Element] = []

    def start(tag, attrib):
        elem = Element(tag, dict(attrib), parser.CurrentLineNumber)
        (stack[-1].children if stack else roots).append(elem)
        stack.append(elem)

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    try:
        with open(path, "rb") as f:
            parser.ParseFile(f)
    except OSError as err:
        raise LaunchFileError(f"cannot read launch file {path}: {err.strerror or err}") from err
    except expat.ExpatError as err:
        raise LaunchFileError(f"{path}: not well-formed XML: {err}") from err
    root = roots[0]
    if root.tag != "launch":
        raise LaunchFileError(f"{path}:{root.line}: the root element is <{root.tag}>, not "
                              "<launch>")
    return root


class _Reader:
    """Walks the elements in document order, as launch visits the actions."""

    def __init__(self, overrides: dict[str, str]):
        self.declared: list[LaunchArg] = []
        self.nodes: list[NodeEntry] = []
        self.depth = 0
        self.top = _Scope(dict(overrides))

    def read_file(self, path: Path, scope: _Scope) -> None:
        self.depth += 1
        if self.depth > MAX_INCLUDE_DEPTH:
            raise LaunchFileError(f"{path}: includes nested deeper than {MAX_INCLUDE_DEPTH} "
                                  "(an include loop?)")
        root = read_xml(path)
        check_attrs(root, Where(path, root.line, "launch"), {"version"}, set())
        self.children(root, path, scope)
        self.depth -= 1

    def children(self, parent: Element, path: Path, scope: _Scope) -> None:
        for elem in parent.children:
            where = Where(path, elem.line, elem.tag)
            if not self.condition(elem, where, scope):
                continue
            handler = getattr(self, "on_" + elem.tag.replace("-", "_"), None)
            if handler is None:
                raise LaunchFileError(f"{where}: unsupported element (supported: arg, let, "
                                      "group, push-ros-namespace, include, node)")
            handler(elem, where, path, scope)

    @staticmethod
    def condition(elem: Element, where: Where, scope: _Scope) -> bool:
        for attr, wanted in (("if", True), ("unless", False)):
            if attr in elem.attrib:
                value = substitute(elem.attrib[attr], scope.variables, where)
                if truth(value, where, attr) != wanted:
                    return False
        return True

    def on_arg(self, elem, where, path, scope) -> None:
        check_attrs(elem, where, {"name", "default", "description"}, {"name"})
        if elem.children:
            raise LaunchFileError(f"{where}: unsupported element <{elem.children[0].tag}> "
                                  "inside <arg> (choices are not supported)")
        name = elem.attrib["name"]
        arg = LaunchArg(name, elem.attrib.get("default"), elem.attrib.get("description", ""))
        if all(a.name != name for a in self.declared):
            self.declared.append(arg)
        if name in scope.variables:
            return
        if arg.default is None:
            raise LaunchFileError(f"{where}: argument {name} is required "
                                  f"({arg.description or 'no description'}); give "
                                  f"{name}:=VALUE")
        scope.variables[name] = substitute(arg.default, scope.variables, where)

    def on_let(self, elem, where, path, scope) -> None:
        check_attrs(elem, where, {"name", "value"}, {"name", "value"})
        name = substitute(elem.attrib["name"], scope.variables, where)
        scope.variables[name] = substitute(elem.attrib["value"], scope.variables, where)

    def on_group(self, elem, where, path, scope) -> None:
        check_attrs(elem, where, {"scoped", "forwarding"}, set())
        scoped = truth(substitute(elem.attrib.get("scoped", "true"), scope.variables, where),
                       where, "scoped")
        forwarding = elem.attrib.get("forwarding", "true")
        if not truth(substitute(forwarding, scope.variables, where), where, "forwarding"):
            raise LaunchFileError(f"{where}: forwarding=\"false\" is not supported")
        self.children(elem, path, scope.copy() if scoped else scope)

    def on_push_ros_namespace(self, elem, where, path, scope) -> None:
        check_attrs(elem, where, {"namespace"}, {"namespace"})
        pushed = substitute(elem.attrib["namespace"], scope.variables, where)
        scope.namespace = absolute_namespace(prefix_namespace(scope.namespace, pushed))

    def on_include(self, elem, where, path, scope) -> None:
        check_attrs(elem, where, {"file"}, {"file"})
        file = Path(substitute(elem.attrib["file"], scope.variables, where))
        values = []  # (name, value text) in order: each sees the ones before it
        for child in elem.children:
            cwhere = Where(path, child.line, child.tag)
            if child.tag != "arg":
                raise LaunchFileError(f"{cwhere}: unsupported element inside <include> "
                                      "(supported: arg)")
            check_attrs(child, cwhere, {"name", "value"}, {"name", "value"})
            if {"if", "unless"} & set(child.attrib):
                raise LaunchFileError(f"{cwhere}: if/unless are not supported here")
            values.append((child, cwhere))
        if not file.is_file():
            raise LaunchFileError(f"{where}: included launch file {file} not found")
        given = [substitute(c.attrib["name"], scope.variables, w) for c, w in values]
        for arg in required_args(read_xml(file)):
            if arg.attrib["name"] not in given:
                raise LaunchFileError(f"{where}: {file} requires argument "
                                      f"{arg.attrib['name']}: give it as <arg> of the <include> "
                                      "(ros2 launch does not take it from the including file)")
        for child, cwhere in values:
            name = substitute(child.attrib["name"], scope.variables, cwhere)
            scope.variables[name] = substitute(child.attrib["value"], scope.variables, cwhere)
        self.read_file(file, scope)

    def on_node(self, elem, where, path, scope) -> None:
        entry = node_entry(elem, where, scope.variables, scope.namespace)
        self.nodes.append(entry)


def required_args(parent: Element):
    """Yield the unconditional ``<arg>``s without default (groups searched, not includes).

    ``ros2 launch`` requires an ``<include>`` to name each of them in its own ``<arg>``s.
    """
    for elem in parent.children:
        if {"if", "unless"} & set(elem.attrib):
            continue
        if elem.tag == "arg" and "default" not in elem.attrib and "name" in elem.attrib:
            yield elem
        elif elem.tag == "group":
            yield from required_args(elem)


def load_launch(path: str | Path, overrides: dict[str, str] | None = None) -> LaunchDescription:
    """Read launch file ``path`` with ``overrides`` (``name -> value``) for its arguments."""
    path = Path(path)
    overrides = dict(overrides or {})
    reader = _Reader(overrides)
    reader.read_file(path, reader.top)
    unknown = set(overrides) - {a.name for a in reader.declared}
    if unknown:
        names = ", ".join(a.name for a in reader.declared) or "none"
        raise LaunchFileError(f"{path.name}: unknown argument(s) {', '.join(sorted(unknown))}"
                              f" (declared: {names})")
    return LaunchDescription(path, reader.declared, reader.top.variables, reader.nodes)
