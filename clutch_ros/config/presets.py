"""Where the shipped parameter presets and the rig DBC live (source tree or installed share).

Looked up in this order: ``$CLUTCH_ROS_PARAMS`` (a directory), the source tree's ``params/``
next to this package, then ``share/clutch_ros/params`` of an installed (colcon) package found
through the ament index.
"""

from __future__ import annotations

import os
from pathlib import Path

from clutch_ros.errors import ConfigError

__all__ = ["params_dir", "preset_path", "default_preset", "PRESETS", "DBC_NAME"]

#: Preset name -> file name in params/.
PRESETS = {
    "flexiforce_8": "flexiforce_8.yaml",
    "test_a": "test_a_organic13.yaml",
    "test_b": "test_b_sintered10.yaml",
    "rig_truth": "rig_truth.yaml",
}
DBC_NAME = "rig.dbc"


def params_dir() -> Path:
    """Return the directory holding the presets and ``rig.dbc``."""
    env = os.environ.get("CLUTCH_ROS_PARAMS")
    if env:
        return Path(env)
    source = Path(__file__).resolve().parents[2] / "params"
    if source.is_dir():
        return source
    try:
        # optional: only an installed (colcon) package has an ament index to look in
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("clutch_ros")) / "params"
    except Exception as err:  # PackageNotFoundError, or ament_index not installed
        raise ConfigError("cannot find the clutch_ros params directory; set "
                          "CLUTCH_ROS_PARAMS") from err


def preset_path(name_or_path: str) -> Path:
    """Resolve a preset name (``flexiforce_8``, ``rig_truth``...) or a file path to a path."""
    if name_or_path in PRESETS:
        return params_dir() / PRESETS[name_or_path]
    if name_or_path == "dbc":
        return params_dir() / DBC_NAME
    path = Path(name_or_path)
    if not path.is_file():
        raise ConfigError(f"no such parameter file or preset: {name_or_path} "
                          f"(presets: {', '.join(PRESETS)})")
    return path


def default_preset(name: str) -> str | None:
    """Return the path of a shipped preset as a string, or None when it cannot be found.

    The nodes use it for their default ``params_file``; a missing preset surfaces when the node
    starts and reads the file, with the error of :func:`preset_path`.
    """
    try:
        return str(preset_path(name))
    except ConfigError:
        return None
