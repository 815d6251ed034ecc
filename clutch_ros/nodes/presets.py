"""Default parameter files of the nodes (resolved at import time of the node module)."""

from clutch_ros.presets import preset_path

__all__ = ["DEFAULT_ESTIMATOR_PRESET", "DEFAULT_RIG_PRESET"]


def _resolve(name: str) -> str | None:
    try:
        return str(preset_path(name))
    except Exception:  # noqa: BLE001 - a missing preset surfaces when the node starts
        return None


DEFAULT_ESTIMATOR_PRESET = _resolve("flexiforce_8")
DEFAULT_RIG_PRESET = _resolve("rig_truth")
