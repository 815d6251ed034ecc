"""Start-up: ``clutch replay`` loads only what replaying needs; the lazy model package works.

Checked by module names, not by time: a fresh interpreter imports the replay subcommand (as
``clutch replay`` does through ``cli/main.py``) and must not have loaded the slow packages
only other subcommands or reports need (scipy.optimize, scipy.stats, scipy.ndimage,
matplotlib, rclpy, distributed, numba). And every public name of ``clutch_ros.model``
resolves, lazily, to the object of its defining module.
"""

import importlib
import json
import subprocess
import sys

import pytest

import clutch_ros.model as model

SLOW = ("scipy.optimize", "scipy.stats", "scipy.ndimage", "matplotlib", "rclpy",
        "distributed", "numba")


def _loaded_after(code: str) -> set[str]:
    probe = f"import sys, json\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, timeout=120).stdout
    return set(json.loads(out.splitlines()[-1]))


def test_replay_subcommand_does_not_load_slow_packages():
    loaded = _loaded_after("from clutch_ros.cli.main import build_parser\n"
                           "build_parser(['replay']).parse_args(['replay', 'b', '--params', 'x'])")
    assert "clutch_ros.cli.replay" in loaded and "clutch_ros.model.pack" in loaded
    assert sorted(m for m in SLOW if m in loaded) == []
    assert "clutch_ros.cli.demo" not in loaded


def test_probe_sees_a_slow_import():
    """The check above can fail: a slow import made by the probed code is seen."""
    assert "scipy.optimize" not in _loaded_after("import clutch_ros.model.inverse")
    loaded = _loaded_after("import clutch_ros.model.inverse\n"
                           "from scipy.optimize import brentq")
    assert "scipy.optimize" in loaded


@pytest.mark.parametrize("name", model.__all__)
def test_every_public_model_name_resolves_to_its_object(name):
    value = getattr(model, name)
    assert not isinstance(value, type(model)), f"{name} resolved to a module"
    module = model._EXPORTS.get(name)
    if module is not None:
        assert value is getattr(importlib.import_module(f"clutch_ros.model.{module}"), name)
    assert name in dir(model)


def test_unknown_model_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        model.no_such_name  # noqa: B018
