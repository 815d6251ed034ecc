"""Where the package's installed data lives: presets, the rig DBC, the dashboard layout.

One lookup for every data file of ``share/clutch_ros`` (:func:`share_file`): the source
checkout this module was imported from (its ``package.xml`` and ``params/``), else the
installed package's share directory found through the ament index (``AMENT_PREFIX_PATH``, set
by ``source install/setup.bash``), as ``ros2 launch``'s ``$(find-pkg-share clutch_ros)`` finds
it. Never Python's ``sys.prefix``: on a rig PC that is ``/usr``, not the colcon install.
``$CLUTCH_ROS_PARAMS`` (a directory) replaces ``params/``.
"""

from __future__ import annotations

import os
from pathlib import Path

from clutch_ros.errors import ConfigError

__all__ = ["DBC_NAME", "LAYOUT_NAME", "PACKAGE", "PRESETS", "default_preset", "params_dir",
           "preset_path", "share_dir", "share_file"]

PACKAGE = "clutch_ros"
#: Preset name -> file name in params/.
PRESETS = {
    "flexiforce_8": "flexiforce_8.yaml",
    "test_a": "test_a_organic13.yaml",
    "test_b": "test_b_sintered10.yaml",
    "rig_truth": "rig_truth.yaml",
    "rig_test_a": "rig_test_a.yaml",
    "rig_truth_elastic": "rig_truth_elastic.yaml",
}
DBC_NAME = "rig.dbc"
#: The Foxglove layout shipped in params/.
LAYOUT_NAME = "clutch_dashboard.json"


def share_dir() -> Path:
    """Return the package's share directory (it holds ``params/`` and ``launch/``).

    The source checkout this module runs from (a development install, ``--symlink-install``)
    or ``share/clutch_ros`` of the installed package, through the ament index. Raises
    :class:`ConfigError` when neither is found.
    """
    source = Path(__file__).resolve().parents[2]
    if (source / "package.xml").is_file() and (source / "params").is_dir():
        return source
    try:
        # optional: only an installed (colcon) package has an ament index to look in
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except Exception as err:  # PackageNotFoundError, or ament_index not installed
        raise ConfigError(f"cannot find the {PACKAGE} share directory: not a source checkout "
                          f"and no {PACKAGE} in the ament index (AMENT_PREFIX_PATH="
                          f"{os.environ.get('AMENT_PREFIX_PATH', '')!r}); source the "
                          "workspace's install/setup.bash") from err


def params_dir() -> Path:
    """Return the directory holding the presets, ``rig.dbc`` and the dashboard layout."""
    env = os.environ.get("CLUTCH_ROS_PARAMS")
    if env:
        return Path(env)
    return share_dir() / "params"


def share_file(name: str) -> Path:
    """Return the path of ``params/<name>`` (``rig.dbc``, ``clutch_dashboard.json``, ...).

    Found as :func:`params_dir` says. The path is returned whether or not the file exists:
    the reader names it when it is missing.
    """
    return params_dir() / name


def preset_path(name_or_path: str) -> Path:
    """Resolve a preset name (``flexiforce_8``, ``rig_truth``...) or a file path to a path."""
    if name_or_path in PRESETS:
        return share_file(PRESETS[name_or_path])
    if name_or_path == "dbc":
        return share_file(DBC_NAME)
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
