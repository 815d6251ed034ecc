"""Substitutions and typed values of the XML launch format, as launch/launch_ros define them.

Used by :mod:`clutch_ros.config.launch_file`. Substitutions (``$(NAME ARG ...)``, nested and
quoted arguments allowed, e.g. ``$(env HOME '')`` or ``$(var $(var which))``):

- ``$(var NAME)``: a launch configuration (``<arg>``, ``<let>``, ``name:=value``).
- ``$(env NAME [DEFAULT])``, ``$(optenv NAME [DEFAULT])`` (unset without default: ``''``).
- ``$(find-pkg-share PKG)``: ``clutch_ros`` only (:func:`clutch_ros.config.presets.share_dir`:
  the source checkout, or the installed ``share/clutch_ros`` found through the ament index).
- ``$(dirname)``, ``$(filename)``: the directory / path of the launch file being read.

Typed values follow launch's rules: a ``<param value=>`` without ``type`` is read as YAML
(``"0"`` is an int, ``"true"`` a bool, ``"[1, 2]"`` a list, ``""`` an empty string); with
``type="str|int|float|bool"`` it is converted to that type. Conditions (``if``/``unless``)
accept ``true``/``1``/``false``/``0`` (any case), as launch's conditions do.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from clutch_ros.config.errors import LaunchFileError
from clutch_ros.config.presets import PACKAGE, share_dir

__all__ = ["PACKAGE", "Where", "check_attrs", "package_share", "substitute", "truth",
           "typed_value"]

SUPPORTED = ("var", "env", "optenv", "find-pkg-share", "dirname", "filename")
_NAME = re.compile(r"[A-Za-z][\w-]*")


@dataclass(frozen=True)
class Where:
    """Position of an element for messages: file, line, element name."""

    file: Path
    line: int
    tag: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: <{self.tag}>"


def package_share(pkg: str = PACKAGE) -> Path:
    """Return the share directory of ``pkg`` (``clutch_ros`` only; see module docstring)."""
    if pkg != PACKAGE:
        raise LaunchFileError(f"$(find-pkg-share {pkg}): only {PACKAGE} is known here")
    return share_dir()


def substitute(text: str, variables: dict[str, str], where: Where) -> str:
    """Return ``text`` with every ``$(...)`` substitution performed."""
    out, pos = _text(text, 0, variables, where, stops="")
    if pos != len(text):  # pragma: no cover - _text only stops early on a stop character
        raise LaunchFileError(f"{where}: cannot read substitution in {text!r}")
    return out


def _text(s: str, i: int, variables, where: Where, stops: str) -> tuple[str, int]:
    """Read literal text and substitutions from ``s[i:]`` up to a character of ``stops``."""
    buf = []
    while i < len(s):
        if s.startswith("$(", i):
            value, i = _call(s, i + 2, variables, where)
            buf.append(value)
            continue
        if s[i] in stops or (" " in stops and s[i].isspace()):
            break
        buf.append(s[i])
        i += 1
    return "".join(buf), i


def _call(s: str, i: int, variables, where: Where) -> tuple[str, int]:
    """Evaluate the substitution whose name starts at ``s[i]``; return it and the end."""
    match = _NAME.match(s, i)
    if not match:
        raise LaunchFileError(f"{where}: cannot read substitution in {s!r}")
    kind, i = match.group(0), match.end()
    args = []
    while True:
        while i < len(s) and s[i].isspace():
            i += 1
        if i >= len(s):
            raise LaunchFileError(f"{where}: unclosed substitution $({kind} ... in {s!r}")
        if s[i] == ")":
            break
        if s[i] in "'\"":
            arg, end = _text(s, i + 1, variables, where, stops=s[i])
            if end >= len(s):
                raise LaunchFileError(f"{where}: unclosed quote in {s!r}")
            i = end + 1
        else:
            arg, i = _text(s, i, variables, where, stops=" )")
        args.append(arg)
    return _apply(kind, args, variables, where), i + 1


def _apply(kind: str, args: list[str], variables, where: Where) -> str:
    n = len(args)
    if kind == "var" and n == 1:
        if args[0] not in variables:
            raise LaunchFileError(f"{where}: $(var {args[0]}): no launch argument or "
                                  f"<let> named {args[0]} is set here")
        return variables[args[0]]
    if kind in ("env", "optenv") and n in (1, 2):
        fallback = args[1] if n == 2 else ("" if kind == "optenv" else None)
        value = os.environ.get(args[0], fallback)
        if value is None:
            raise LaunchFileError(f"{where}: environment variable {args[0]} is not set")
        return value
    if kind == "find-pkg-share" and n == 1:
        try:
            return str(package_share(args[0]))
        except LaunchFileError as err:
            raise LaunchFileError(f"{where}: {err}") from None
    if kind == "dirname" and n == 0:
        return str(where.file.resolve().parent)
    if kind == "filename" and n == 0:
        return str(where.file.resolve())
    if kind in SUPPORTED:
        raise LaunchFileError(f"{where}: $({kind}) with {n} argument(s) is not valid")
    raise LaunchFileError(f"{where}: unsupported substitution $({kind} ...) (supported: "
                          f"{', '.join(f'$({k})' for k in SUPPORTED)})")


def truth(value: str, where: Where, attr: str) -> bool:
    """Evaluate a condition or boolean attribute (``true``/``1``/``false``/``0``)."""
    text = value.strip().lower()
    if text in ("true", "1"):
        return True
    if text in ("false", "0"):
        return False
    raise LaunchFileError(f"{where}: {attr}={value!r} is not true, false, 1 or 0")


def typed_value(text: str, type_id: str | None, where: Where, name: str) -> Any:
    """Return the value of ``<param name value [type]>`` as ``ros2 launch`` gives it to the node."""
    if type_id == "str":
        return text
    if type_id in ("int", "float"):
        try:
            return int(text) if type_id == "int" else float(text)
        except ValueError:
            raise LaunchFileError(f"{where}: parameter {name}: {text!r} is not "
                                  f"{type_id}") from None
    if type_id == "bool":
        text = {"1": "true", "0": "false"}.get(text, text)
    elif type_id is not None:
        raise LaunchFileError(f"{where}: parameter {name}: type={type_id!r} is not supported "
                              "(str, int, float, bool)")
    try:
        value = yaml.safe_load(text if text else "''")
    except yaml.YAMLError:
        raise LaunchFileError(f"{where}: parameter {name}: {text!r} is not valid YAML (give "
                              "type=\"str\" for a string)") from None
    if type_id == "bool" and not isinstance(value, bool):
        raise LaunchFileError(f"{where}: parameter {name}: {text!r} is not bool")
    if isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, list) and value and len({type(v) for v in value}) == 1 \
            and isinstance(value[0], (bool, int, float, str)):
        return value
    raise LaunchFileError(f"{where}: parameter {name}: {text!r} is neither a scalar nor a "
                          "non-empty list of one type (give type=\"str\" for a string)")


def check_attrs(elem, where: Where, allowed: set[str], required: set[str]) -> None:
    """Refuse attributes outside ``allowed`` (plus if/unless) and missing ``required`` ones."""
    unknown = set(elem.attrib) - allowed - {"if", "unless"}
    if unknown:
        raise LaunchFileError(f"{where}: unsupported attribute(s) {', '.join(sorted(unknown))}"
                              f" (supported: {', '.join(sorted(allowed))}, if, unless)")
    missing = required - set(elem.attrib)
    if missing:
        raise LaunchFileError(f"{where}: missing attribute(s) {', '.join(sorted(missing))}")
