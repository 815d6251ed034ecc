"""Read and write ROS 2 parameter YAML files holding the model parameters (and others).

Format (what ``ros2 run ... --params-file`` accepts)::

    /**:                      # or a node name: estimator, /rig1/estimator, /**/estimator
      ros__parameters:
        clutch:
          lamella_count: 8
        friction:
          mu_ref: 0.12

Nested mappings are flattened to dotted keys (``clutch.lamella_count``); lists are kept as
values. :func:`load_flat` returns every key (nodes keep their own keys in the same file);
:func:`load_params` validates the model keys into :class:`~clutch_ros.model.ClutchParams`
(other namespaces are ignored). Errors are :class:`~clutch_ros.errors.ConfigError` (file
missing, YAML syntax, layout) or :class:`~clutch_ros.model.ParameterError` (a bad model key),
always with the file name.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from clutch_ros.errors import ConfigError
from clutch_ros.model.errors import ParameterError
from clutch_ros.model.params import NAMESPACES, ClutchParams

__all__ = ["load_flat", "load_params", "load_yaml", "write_params", "flatten", "nest"]

_WILDCARDS = ("/**", "**")


def flatten(tree: Mapping[str, Any], prefix: str = "", source: str = "") -> dict[str, Any]:
    """Flatten nested mappings to ``{dotted.key: value}``."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        if not isinstance(key, str) or not key:
            raise ConfigError(f"{source}: parameter name {key!r} is not a string")
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, dotted + ".", source))
        else:
            flat[dotted] = value
    return flat


def nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten`."""
    tree: dict[str, Any] = {}
    for key, value in flat.items():
        node = tree
        parts = key.split(".")
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"parameter '{key}' clashes with the value of '{part}'")
            node = child
        if isinstance(node.get(parts[-1]), dict):
            raise ConfigError(f"parameter '{key}' clashes with nested keys below it")
        node[parts[-1]] = value
    return tree


def _matches(section: str, node: str | None) -> bool:
    if section in _WILDCARDS:
        return True
    if node is None:
        return False
    name = node.strip("/").split("/")[-1]
    sec = section.strip("/")
    return sec == node.strip("/") or sec == name or sec == f"**/{name}"


def load_yaml(path, what: str) -> Any:
    """Parse the YAML file ``path``; errors raise a one-line :class:`ConfigError`.

    ``what`` names the file's role in the messages (e.g. ``"parameter file"``). Unreadable
    files, bad encodings and YAML syntax errors (with the line number) are reported.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read {what} ({err.strerror or err})") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: {what} is not UTF-8 text ({err.reason})") from err
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{path}:{where} invalid YAML: "
                          f"{getattr(err, 'problem', None) or err}") from err


def load_flat(path, node: str | None = None) -> dict[str, Any]:
    """Return all parameters of ``path`` as dotted keys.

    Sections ``/**`` apply to every node; with ``node`` (e.g. ``"estimator"``) the sections
    naming it are merged on top. Without ``node`` a file holding exactly one (non-wildcard)
    section is read from that section.
    """
    path = Path(path)
    source = str(path)
    data = load_yaml(path, "parameter file")
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"{source}: expected a ROS 2 parameter file ('/**:' -> "
                          "'ros__parameters:' -> parameters)")
    sections = [str(k) for k in data]
    chosen = [s for s in sections if _matches(s, node)]
    if not chosen and node is None and len(sections) == 1:
        chosen = sections
    if not chosen:
        raise ConfigError(f"{source}: no parameter section for "
                          f"{'any node' if node is None else node!r} (found {sections})")
    chosen.sort(key=lambda s: s not in _WILDCARDS)  # wildcards first, node sections override
    flat: dict[str, Any] = {}
    for section in chosen:
        body = data[section]
        if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"),
                                                           Mapping):
            raise ConfigError(f"{source}: section '{section}' needs a 'ros__parameters:' "
                              "mapping")
        flat.update(flatten(body["ros__parameters"], source=source))
    return flat


def load_params(path, node: str | None = None) -> ClutchParams:
    """Load and validate the model parameters of ``path`` (other namespaces ignored)."""
    flat = load_flat(path, node)
    try:
        return ClutchParams.from_flat(flat)
    except ParameterError as err:
        raise err.with_source(str(path)) from None


def write_params(params: ClutchParams, path, extra: Mapping[str, Any] | None = None,
                 header: str | None = None) -> Path:
    """Write a complete parameter file (``/**: ros__parameters:``) that loads back unchanged.

    ``extra`` adds non-model keys (dotted, e.g. ``{"estimator.max_gap": 1.0}``); model keys
    in it are refused (the parameters come from ``params``). Floats stay floats, so ROS reads
    them as doubles. The file is written atomically.
    """
    flat: dict[str, Any] = dict(params.to_flat())
    for key, value in (extra or {}).items():
        if key.split(".", 1)[0] in NAMESPACES:
            raise ConfigError(f"{path}: extra key '{key}' is a model parameter; change "
                              "ClutchParams instead")
        flat[key] = value
    doc = {"/**": {"ros__parameters": nest(flat)}}
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    lines = [f"# {line}" for line in (header or "clutch_ros parameters").splitlines()]
    lines.append("# ROS 2 parameter file; SI units, temperatures in degC.")
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n" + text)
        os.replace(tmp, path)
    except OSError as err:
        raise ConfigError(f"{path}: cannot write parameter file ({err})") from err
    return path
