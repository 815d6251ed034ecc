"""Read the subset of the ROS 2 XML launch format that the package's launch files use.

``ros2 launch`` (launch, launch_ros, launch_xml) is not on the package index, so
``clutch up`` starts the node set of ``launch/*.launch.xml`` itself from what this module
reads. The files stay valid ``ros2 launch`` files: only elements, attributes and
substitutions that launch_xml defines with the same meaning are accepted, anything else is a
:class:`LaunchFileError` naming it (never silently ignored).

Elements:
- ``<launch>``: the root.
- ``<arg name= default= description=/>``: an argument; ``name:=value`` on the command line
  overrides the default; an argument without default must be given.
- ``<let name= value=/>``: set a variable (later ``$(var ...)`` see it).
- ``<node pkg= exec= name= namespace= if= unless=>``: one node process, with children
  ``<param name= value=/>`` (one parameter, value as YAML like ``-p``), ``<param from=/>`` (a
  parameter file, ``--params-file``) and ``<remap from= to=/>``.

Substitutions inside attribute values: ``$(var NAME)``, ``$(env NAME [DEFAULT])``,
``$(find-pkg-share PKG)`` (``clutch_ros`` only: the directory that holds ``params/`` and
``launch/``, i.e. the source tree or the installed ``share/clutch_ros``).
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from clutch_ros.config.errors import LaunchFileError  # re-exported: its old home
from clutch_ros.config.presets import params_dir

__all__ = ["LaunchArg", "LaunchDescription", "LaunchFileError", "NodeEntry", "load_launch",
           "package_share", "parse_overrides"]

PACKAGE = "clutch_ros"
_SUBST = re.compile(r"\$\(([a-z-]+)((?:\s+[^()\s]+)*)\s*\)")
_NODE_ATTRS = {"pkg", "exec", "name", "namespace", "if", "unless", "output"}
_TRUE, _FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")


@dataclass(frozen=True)
class LaunchArg:
    """A declared ``<arg>``: its name, default (None: required) and description."""

    name: str
    default: str | None
    description: str = ""


@dataclass
class NodeEntry:
    """One ``<node>`` with every substitution resolved."""

    pkg: str
    executable: str
    name: str
    namespace: str = "/"
    params: list[tuple[str, str]] = field(default_factory=list)
    param_files: list[str] = field(default_factory=list)
    remaps: list[tuple[str, str]] = field(default_factory=list)

    @property
    def full_name(self) -> str:
        """Return the fully qualified node name (``/rig1/estimator``)."""
        return f"{self.namespace.rstrip('/')}/{self.name}"

    def ros_args(self) -> list[str]:
        """Return the ``--ros-args ...`` arguments ``ros2 launch`` would give the node.

        Parameter files first, then single parameters (later ones win), then remappings.
        """
        args = ["--ros-args", "-r", f"__node:={self.name}", "-r", f"__ns:={self.namespace}"]
        for path in self.param_files:
            args += ["--params-file", path]
        for name, value in self.params:
            args += ["-p", f"{name}:={value}"]
        for src, dst in self.remaps:
            args += ["-r", f"{src}:={dst}"]
        return args


@dataclass
class LaunchDescription:
    """What a launch file starts: its declared arguments, the values used, the nodes."""

    path: Path
    args: list[LaunchArg]
    values: dict[str, str]
    nodes: list[NodeEntry]


def package_share(pkg: str = PACKAGE) -> Path:
    """Return the share directory of ``pkg`` (``clutch_ros`` only; see module docstring)."""
    if pkg != PACKAGE:
        raise LaunchFileError(f"$(find-pkg-share {pkg}): only {PACKAGE} is known here")
    return params_dir().parent


def parse_overrides(items: list[str]) -> dict[str, str]:
    """Parse command-line ``name:=value`` items into a mapping."""
    out = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name or not re.fullmatch(r"[A-Za-z_][\w.-]*", name):
            raise LaunchFileError(f"launch argument {item!r} is not name:=value")
        out[name] = value
    return out


def _substitute(text: str, variables: dict[str, str], where: str) -> str:
    def one(match: re.Match) -> str:
        kind, rest = match.group(1), match.group(2).split()
        if kind == "var" and len(rest) == 1:
            if rest[0] not in variables:
                raise LaunchFileError(f"{where}: $(var {rest[0]}) is not a declared argument")
            return variables[rest[0]]
        if kind == "env" and len(rest) in (1, 2):
            value = os.environ.get(rest[0], rest[1] if len(rest) == 2 else None)
            if value is None:
                raise LaunchFileError(f"{where}: environment variable {rest[0]} is not set")
            return value
        if kind == "find-pkg-share" and len(rest) == 1:
            return str(package_share(rest[0]))
        raise LaunchFileError(f"{where}: unsupported substitution {match.group(0)!r} "
                              "(supported: $(var N), $(env N [D]), $(find-pkg-share P))")

    out = _SUBST.sub(one, text)
    if "$(" in out:
        raise LaunchFileError(f"{where}: cannot read substitution in {text!r}")
    return out


def _attrs(elem: ET.Element, allowed: set[str], required: set[str], where: str) -> None:
    unknown = set(elem.attrib) - allowed
    if unknown:
        raise LaunchFileError(f"{where}: unsupported attribute(s) {', '.join(sorted(unknown))}")
    missing = required - set(elem.attrib)
    if missing:
        raise LaunchFileError(f"{where}: missing attribute(s) {', '.join(sorted(missing))}")


def _truth(value: str, where: str) -> bool:
    if value.strip().lower() in _TRUE:
        return True
    if value.strip().lower() in _FALSE:
        return False
    raise LaunchFileError(f"{where}: {value!r} is not true or false")


def _node(elem: ET.Element, variables: dict[str, str], where: str) -> NodeEntry | None:
    _attrs(elem, _NODE_ATTRS, {"pkg", "exec"}, where)
    sub = {k: _substitute(v, variables, where) for k, v in elem.attrib.items()}
    if "if" in sub and not _truth(sub["if"], where + " if"):
        return None
    if "unless" in sub and _truth(sub["unless"], where + " unless"):
        return None
    namespace = sub.get("namespace", "/") or "/"
    if not namespace.startswith("/"):
        namespace = "/" + namespace
    entry = NodeEntry(sub["pkg"], sub["exec"], sub.get("name", sub["exec"]), namespace)
    for child in elem:
        cwhere = f"{where} <{child.tag}>"
        if child.tag == "param" and "from" in child.attrib:
            _attrs(child, {"from"}, {"from"}, cwhere)
            entry.param_files.append(_substitute(child.attrib["from"], variables, cwhere))
        elif child.tag == "param":
            _attrs(child, {"name", "value"}, {"name", "value"}, cwhere)
            entry.params.append((_substitute(child.attrib["name"], variables, cwhere),
                                 _substitute(child.attrib["value"], variables, cwhere)))
        elif child.tag == "remap":
            _attrs(child, {"from", "to"}, {"from", "to"}, cwhere)
            entry.remaps.append((_substitute(child.attrib["from"], variables, cwhere),
                                 _substitute(child.attrib["to"], variables, cwhere)))
        else:
            raise LaunchFileError(f"{cwhere}: unsupported element inside <node>")
    return entry


def load_launch(path: str | Path, overrides: dict[str, str] | None = None) -> LaunchDescription:
    """Read launch file ``path`` with ``overrides`` (``name -> value``) for its arguments."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as err:
        raise LaunchFileError(f"cannot read launch file {path}: {err.strerror or err}") from err
    except ET.ParseError as err:
        raise LaunchFileError(f"{path}: not well-formed XML: {err}") from err
    if root.tag != "launch":
        raise LaunchFileError(f"{path}: the root element is <{root.tag}>, not <launch>")
    overrides = dict(overrides or {})
    declared: list[LaunchArg] = []
    variables: dict[str, str] = {}
    nodes: list[NodeEntry] = []
    for index, elem in enumerate(root, start=1):
        where = f"{path.name}: <{elem.tag}> #{index}"
        if elem.tag == "arg":
            _attrs(elem, {"name", "default", "description"}, {"name"}, where)
            arg = LaunchArg(elem.attrib["name"], elem.attrib.get("default"),
                            elem.attrib.get("description", ""))
            declared.append(arg)
            if arg.name in overrides:
                variables[arg.name] = overrides.pop(arg.name)
            elif arg.default is not None:
                variables[arg.name] = _substitute(arg.default, variables, where)
            else:
                raise LaunchFileError(f"{path.name}: argument {arg.name} is required "
                                      f"({arg.description or 'no description'}); give "
                                      f"{arg.name}:=VALUE")
        elif elem.tag == "let":
            _attrs(elem, {"name", "value"}, {"name", "value"}, where)
            variables[elem.attrib["name"]] = _substitute(elem.attrib["value"], variables, where)
        elif elem.tag == "node":
            entry = _node(elem, variables, where)
            if entry is not None:
                nodes.append(entry)
        else:
            raise LaunchFileError(f"{where}: unsupported element (supported: arg, let, node)")
    if overrides:
        names = ", ".join(a.name for a in declared) or "none"
        raise LaunchFileError(f"{path.name}: unknown argument(s) {', '.join(sorted(overrides))}"
                              f" (declared: {names})")
    return LaunchDescription(path, declared, variables, nodes)
