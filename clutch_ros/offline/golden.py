"""Golden regression data: simulated Table 3/4 bags and the estimator's expected outputs.

Layout of a golden directory (``tests/data/golden``)::

    bags/<run>/            RigState bag (MCAP, zstd chunks) of one simulated run, 100 Hz
    expected/<run>.npz     stamp_ns, modelled_torque, reference_torque, pressure_difference
                           at every sample the estimator publishes (flexiforce_8 preset)
    expected.json          per run the replay summary figures, plus the generator settings
                           and the preset's parameters the outputs were computed with

:func:`generate_bags` simulates the runs (:data:`~clutch_ros.offline.rig_runs.GOLDEN_RUNS`);
:func:`compute_expected` replays one bag through :func:`clutch_ros.offline.replay.replay_bag`
(the ``clutch replay`` code path); :func:`compare_series` / :func:`compare_summary` return a
readable diff (where, by how much) against :data:`TOLERANCES`, or nothing when within them.
``tools/make_golden.py`` is the command line; ``tests/bag/test_golden.py`` the test.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros.offline.replay import published_rows, replay_bag
from clutch_ros.offline.rig_runs import GOLDEN_RUNS, golden_scenario, simulate_run, write_run

__all__ = [
    "FIELDS",
    "PLANT",
    "PRESET",
    "RATE_HZ",
    "SUMMARY_KEYS",
    "TOLERANCES",
    "bag_path",
    "compare_series",
    "compare_summary",
    "compute_expected",
    "expected_path",
    "generate_bags",
    "load_expected",
    "load_manifest",
    "write_expected",
]

#: Estimator preset the expected outputs are computed with.
PRESET = "flexiforce_8"
#: Truth plant of the golden bags: the rig's truth plant behind its elastic drivetrain, so the
#: runs show the torque build-up and the stuck clutch of the thesis's rig (the preset's header
#: says why; a rigid plant cannot show either).
PLANT = "rig_truth_elastic"
#: Sample rate of the golden bags [Hz] (the rig simulates at 1 kHz; every 10th sample kept).
RATE_HZ = 100.0
#: Per-sample outputs stored for every run.
FIELDS = ("modelled_torque", "reference_torque", "pressure_difference")
#: Summary figures stored for every run (those of ``clutch replay --json``).
SUMMARY_KEYS = (
    "samples", "accepted", "law", "rmse_nm", "reference_rmse_nm", "within_10pct",
    "reference_within_10pct", "max_accuracy", "min_accuracy",
)  # fmt: skip

#: name -> (rtol, atol, unit). The computation is deterministic; the tolerances only absorb
#: last-bit differences between numpy/scipy/BLAS builds (~1e-12 relative), while any model
#: change that moves a torque by 0.1 mN m (or P_diff by 0.01 Pa) fails.
TOLERANCES: dict[str, tuple[float, float, str]] = {
    "modelled_torque": (1e-7, 1e-4, "N m"),  # values up to ~1.5 kN m
    "reference_torque": (1e-7, 1e-4, "N m"),
    "pressure_difference": (1e-7, 1e-2, "Pa"),  # values up to ~6e5 Pa
    "rmse_nm": (1e-7, 1e-6, "N m"),
    "reference_rmse_nm": (1e-7, 1e-6, "N m"),
    "max_accuracy": (1e-6, 1e-9, ""),
    "min_accuracy": (1e-6, 1e-9, ""),
    # a fraction of counted samples: one sample on the band edge may flip (atol set per run)
    "within_10pct": (0.0, 0.0, ""),
    "reference_within_10pct": (0.0, 0.0, ""),
}


def bag_path(root: str | Path, name: str) -> Path:
    """Golden bag of run ``name`` under ``root``."""
    return Path(root) / "bags" / name


def expected_path(root: str | Path, name: str) -> Path:
    """Return the expected per-sample outputs file of run ``name`` under ``root``."""
    return Path(root) / "expected" / f"{name}.npz"


def generate_bags(root: str | Path, names: Iterable[str] | None = None) -> list[Path]:
    """(Re)write the golden bags of ``names`` (default: all) from the simulated rig."""
    out = []
    for name in names or GOLDEN_RUNS:
        scenario, seed = golden_scenario(name)
        run = simulate_run(scenario, seed=seed, rate_hz=RATE_HZ, plant=PLANT,
                           wheel_speeds=False)
        run.columns["ff_voltages"] = np.zeros((len(run), 0))  # not read by the estimator
        path = bag_path(root, name)
        if path.exists():
            shutil.rmtree(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_run(path, run, compression="zstd", custom_data={"clutch_ros.golden": name})
        out.append(path)
    return out


def compute_expected(bag: str | Path, params: Any) -> tuple[dict[str, np.ndarray], dict]:
    """Replay ``bag``: per-sample outputs (published rows) and the summary figures."""
    result = replay_bag(bag, params)
    rows = published_rows(result.batch)
    arrays = {"stamp_ns": result.rig.stamp_ns[rows]}
    arrays.update({f: np.asarray(getattr(result.batch, f)[rows], dtype=float) for f in FIELDS})
    summary = {k: result.summary[k] for k in SUMMARY_KEYS}
    summary["counted"] = _counted(result)
    return arrays, summary


def _counted(result: Any) -> int:
    """Count the samples the within-10 % fraction is taken over (for its tolerance)."""
    batch = result.batch
    ok = batch.accepted
    meas = batch.measured_torque[ok]
    finite = np.isfinite(meas)
    if not finite.any():
        return 0
    threshold = 0.05 * float(np.max(np.abs(meas[finite])))
    acc = batch.torque_accuracy[ok]
    with np.errstate(invalid="ignore"):
        return int((finite & (np.abs(meas) >= threshold) & np.isfinite(acc)).sum())


def write_expected(root: str | Path, results: Mapping[str, tuple[dict, dict]], meta: dict) -> None:
    """Write ``expected/<run>.npz`` and ``expected.json`` for ``results`` (run -> outputs)."""
    root = Path(root)
    (root / "expected").mkdir(parents=True, exist_ok=True)
    summaries = {}
    for name, (arrays, summary) in results.items():
        np.savez_compressed(expected_path(root, name), **arrays)
        summaries[name] = summary
    doc = dict(meta)
    doc["runs"] = summaries
    (root / "expected.json").write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")


def load_manifest(root: str | Path) -> dict:
    """Return ``expected.json``."""
    return json.loads((Path(root) / "expected.json").read_text())


def load_expected(root: str | Path, name: str) -> dict[str, np.ndarray]:
    """Return the stored per-sample outputs of run ``name``."""
    with np.load(expected_path(root, name)) as data:
        return {k: data[k] for k in data.files}


def compare_series(
    run: str,
    field: str,
    expected: np.ndarray,
    actual: np.ndarray,
    time_s: np.ndarray,
) -> str | None:
    """Return a readable diff of one per-sample output, or None within :data:`TOLERANCES`."""
    rtol, atol, unit = TOLERANCES[field]
    exp = np.asarray(expected, dtype=float)
    act = np.asarray(actual, dtype=float)
    if exp.shape != act.shape:
        return f"{run} {field}: {act.shape[0]} samples, expected {exp.shape[0]}"
    dev = np.abs(act - exp)
    with np.errstate(invalid="ignore"):
        bad = ~(dev <= atol + rtol * np.abs(exp)) & ~(np.isnan(exp) & np.isnan(act))
    if not bad.any():
        return None
    dev = np.where(np.isnan(dev), np.inf, dev)
    worst = int(np.argmax(np.where(bad, dev, -1.0)))
    first = int(np.argmax(bad))
    unit = f" {unit}" if unit else ""
    return (
        f"{run} {field}: {int(bad.sum())} of {len(exp)} samples outside rtol={rtol:g}, "
        f"atol={atol:g}{unit}; max |deviation| {dev[worst]:.6g}{unit} at sample {worst} "
        f"(t = {time_s[worst]:.3f} s): expected {exp[worst]:.10g}, got {act[worst]:.10g}; "
        f"first at sample {first} (t = {time_s[first]:.3f} s): expected {exp[first]:.10g}, "
        f"got {act[first]:.10g}"
    )


def compare_summary(run: str, expected: Mapping[str, Any], actual: Mapping[str, Any]) -> list[str]:
    """Return the summary figures of ``run`` that differ beyond :data:`TOLERANCES`."""
    out = []
    for key in SUMMARY_KEYS:
        exp, act = expected.get(key), actual.get(key)
        if key not in TOLERANCES:
            if exp != act:
                out.append(f"{run} {key}: expected {exp!r}, got {act!r}")
            continue
        rtol, atol, unit = TOLERANCES[key]
        if key.endswith("within_10pct"):  # one counted sample may flip at the band edge
            atol = 1.0 / max(int(expected.get("counted") or 1), 1) + 1e-12
        e = float("nan") if exp is None else float(exp)
        a = float("nan") if act is None else float(act)
        if np.isnan(e) and np.isnan(a):
            continue
        if not abs(a - e) <= atol + rtol * abs(e):
            unit = f" {unit}" if unit else ""
            out.append(
                f"{run} {key}: expected {e:.10g}{unit}, got {a:.10g}{unit} "
                f"(deviation {a - e:+.3g}{unit}; rtol={rtol:g}, atol={atol:g})"
            )
    return out
