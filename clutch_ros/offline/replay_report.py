"""PNG report of replayed bags (``clutch replay --report DIR``).

:class:`ReplayReport` collects the replayed bags and writes, into ``DIR``:

- per bag ``<bag>_replay.png`` (:func:`plot_replay`): measured vs modelled vs reference
  (Eq. 1) torque, the torque accuracy of model and reference with the ±10 % band, the
  modelled P_diff, and the RMSE of model and reference side by side;
- with several bags ``replay_summary.png`` (:func:`plot_summary`): per bag (sequence) the
  RMSE and the share of samples within ±10 % of reference and model;
- the thesis's validation views (:mod:`clutch_ros.offline.validation_report`):
  ``validation_rmse.png`` (Fig. 57, RMSE per sequence, reference vs model) and per bag
  ``validation_accuracy_<bag>.png`` (Figs. 55-56), ``validation_pdiff_<bag>.png`` (Fig. 54:
  measured P_diff, the model's P_diff and its spline force) and ``validation_xcorr_<bag>.png``
  (the residual cross-correlation of Eq. 3 with its 99 % band).

The measured P_diff comes from the bags' FlexiForce voltages, calibrated on the replayed bags
themselves like ``clutch fit`` does
(:func:`clutch_ros.offline.flexiforce.flexiforce_pressures`, "same
force" method unless told otherwise, thesis §5.5) or with a given calibration (a single ramp
has no quasi-static plateaus to calibrate on); bags without voltages show the modelled curves
only. With a measured P_diff the bag's summary gains its RMSE against the model's P_diff.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from clutch_ros.model.metrics import rmse
from clutch_ros.offline.flexiforce import (
    check_sensor_count,
    flexiforce_pressures,
    flexiforce_voltages,
)
from clutch_ros.offline.plots import new_figure, save_figure
from clutch_ros.offline.validation_report import evaluation_from_batch, write_report

__all__ = ["ReplayReport", "plot_replay", "plot_summary"]


class ReplayReport:
    """Collect replayed bags (:meth:`add`), then write the overview views (:meth:`finish`).

    Args:
        out_dir: report directory (created).
        params: the replay's ``ClutchParams`` (piston area for the pressure equivalents).
        label: model label in legends and the summary (e.g. the spline law).
        calibration: FlexiForce calibration method fitted on the bags (``same_force`` or
            ``same_sensor``).
        fixed_calibration: a ``SensorCalibration`` to use instead of fitting one.
        figures: a dict to keep every saved ``Figure`` in, by path (inspection, tests).

    Only what the views need is kept per bag (the evaluation's arrays, the FlexiForce
    voltages), not the whole replay.
    """

    def __init__(self, out_dir: Path, params, label: str, *, calibration: str = "same_force",
                 fixed_calibration=None, figures: dict | None = None):
        self.figures = figures
        self.out_dir = Path(out_dir)
        self.calibration = calibration
        self.fixed_calibration = fixed_calibration
        self.params = params
        self.label = label
        self._runs: list = []  # (evaluation, accepted mask, voltage view)

    def add(self, result) -> list[str]:
        """Plot one ``ReplayResult`` (``<bag>_replay.png``); return the paths written."""
        rig, batch = result.rig, result.batch
        ff = rig.columns.get("ff_voltages")
        volts = SimpleNamespace(  # what flexiforce_pressures reads of a RigStateArrays
            time=rig.time, actuating_pressure=rig.actuating_pressure, ff_voltages=ff,
            columns={k: v for k, v in rig.columns.items() if k == "ff_voltages.len"})
        v = flexiforce_voltages(volts)
        if self.fixed_calibration is not None and v is not None:  # fail before any plot
            check_sensor_count(self.fixed_calibration, {v.shape[1]}, f"{result.bag}: ")
        paths = plot_replay(result.bag, rig, batch, self.out_dir, figures=self.figures)
        names = {ev.name for ev, _, _ in self._runs}
        name = Path(result.bag).name or "bag"
        if name in names:  # two bags of the same folder name: keep their files apart
            name = f"{name}_{len(self._runs)}"
        ev = evaluation_from_batch(name, rig.time, batch)
        self._runs.append((ev, np.asarray(batch.accepted, dtype=bool), volts))
        return [str(p) for p in paths]

    def finish(self, summaries: list[dict]) -> list[str]:
        """Write the overview and validation views; extend each bag's summary.

        ``summaries``: the bags' summaries in :meth:`add` order; each gains the paths of its
        views in ``plots`` and a ``validation`` object (``xcorr_outside``: fraction of lags
        outside the band per model, ``measured_pdiff``: calibration method or None,
        ``calibration_error``). Returns every path written here.
        """
        written = []
        if len(summaries) > 1:
            overview = str(plot_summary(summaries, self.out_dir, figures=self.figures))
            written.append(overview)
            for summary in summaries:
                summary["plots"].append(overview)
        area = self.params.pack.piston_area
        discs, info = flexiforce_pressures([v for _, _, v in self._runs], area,
                                           calibration=self.calibration,
                                           fixed=self.fixed_calibration)
        evaluations = []
        for (ev, ok, _), pressures in zip(self._runs, discs):
            if pressures is not None:
                ev = replace(ev, measured_pdiff=(pressures[0] - pressures[1])[ok])
            evaluations.append(ev)
        paths, report = write_report({self.label: evaluations}, self.out_dir, area=area,
                                     figures=self.figures)
        written += [str(p) for p in paths]
        cal = info["calibration"]
        for summary, ev in zip(summaries, evaluations):
            summary["plots"] += [str(report["rmse_file"])] + [str(p) for p in
                                                             report["files"][ev.name]]
            summary["validation"] = {
                "xcorr_outside": report["xcorr_outside"][ev.name],
                "measured_pdiff": (cal.method if cal is not None
                                   and ev.measured_pdiff is not None else None),
                "calibration_error": info["calibration_error"],
                "calibration_source": (None if cal is None else "file"
                                       if self.fixed_calibration is not None else "bags"),
                "pdiff_rmse_pa": _pdiff_rmse(ev),
            }
        return written


def _pdiff_rmse(ev) -> float | None:
    """RMSE of measured − modelled P_diff [Pa] over the finite pairs, or None."""
    if ev.measured_pdiff is None:
        return None
    value = rmse(ev.measured_pdiff, ev.pressure_difference)
    return None if math.isnan(value) else value


def plot_replay(bag: Path, rig, batch, out_dir: Path, *,
                figures: dict | None = None) -> list[Path]:
    """Write ``<bag name>_replay.png`` into ``out_dir``; return the paths written.

    The title names the bag and the spline law; ``figures``: see
    :func:`~clutch_ros.offline.plots.save_figure`.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    t = rig.time
    ok = batch.accepted
    meas = batch.measured_torque
    law = batch.spline_law
    fig = new_figure((11, 10.5), dpi=100)
    axes = fig.subplots(4, 1, gridspec_kw={"height_ratios": [3, 2, 2, 1.6]})
    for ax in axes[:2]:  # one time axis for the curves, labelled under P_diff
        ax.sharex(axes[2])
        ax.tick_params(labelbottom=False)
    ax = axes[0]
    ax.plot(t, meas, color="tab:blue", lw=0.8, label="measured")
    ax.plot(t, batch.modelled_torque, color="tab:red", lw=0.9, label=f"model ({law})")
    ax.plot(t, batch.reference_torque, color="tab:orange", lw=0.8, ls="--",
            label="reference (Eq. 1)")
    ax.set_ylabel("torque [N m]")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        big = np.abs(meas) > 0.05 * np.nanmax(np.abs(meas)) if np.isfinite(meas).any() else ok
        acc_model = np.where(big, meas / batch.modelled_torque, np.nan)
        acc_ref = np.where(big, meas / batch.reference_torque, np.nan)
    ax.axhspan(0.9, 1.1, color="tab:green", alpha=0.15)
    ax.plot(t, acc_ref, color="tab:orange", lw=0.8, label="reference")
    ax.plot(t, acc_model, color="tab:red", lw=0.8, label="model")
    ax.set_ylim(0.6, 1.4)
    ax.set_ylabel("accuracy,\nmeasured / modelled [-]")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[2]
    ax.plot(t, batch.pressure_difference / 1e5, color="tab:red", lw=0.9,
            label="P_diff modelled")
    ax.set_ylabel("P_diff [bar]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[3]
    values = [rmse(meas[ok], batch.reference_torque[ok]), rmse(meas[ok], batch.modelled_torque[ok])]
    ax.barh(["reference (Eq. 1)", f"model ({law})"], values, color=["tab:orange", "tab:red"])
    ax.set_ylabel("torque from")
    ax.set_xlabel("RMSE against the measured torque [N m]")
    fig.suptitle(f"replay of {Path(bag).name}, spline law {law}")
    return [save_figure(fig, out_dir / f"{Path(bag).name}_replay.png", figures)]


def plot_summary(results: list[dict], out_dir: Path, *, figures: dict | None = None) -> Path:
    """Write ``replay_summary.png``: RMSE and within-±10 % per bag, reference vs model.

    ``results``: the bags' replay summaries (``bag``, ``law``, ``rmse_nm``,
    ``within_10pct`` and their ``reference_`` counterparts); ``figures``: see
    :func:`~clutch_ros.offline.plots.save_figure`.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [Path(r["bag"]).name for r in results]
    laws = ", ".join(dict.fromkeys(r["law"] for r in results))
    y = np.arange(len(results))
    fig = new_figure((12, 1.6 + 0.45 * len(results)), dpi=100)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (key, ref_key, label, scale) in zip(axes, (
            ("rmse_nm", "reference_rmse_nm", "torque RMSE [N m]", 1.0),
            ("within_10pct", "reference_within_10pct", "samples within ±10 % [%]", 100.0))):
        ref = [scale * float(r.get(ref_key, float("nan"))) for r in results]
        model = [scale * float(r[key]) for r in results]
        ax.barh(y + 0.2, ref, height=0.4, color="tab:orange", label="reference (Eq. 1)")
        ax.barh(y - 0.2, model, height=0.4, color="tab:red", label=f"model ({laws})")
        ax.set_xlabel(label)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, names, fontsize=8)
    axes[0].set_ylabel("run (bag name)")
    axes[0].invert_yaxis()
    axes[1].legend(fontsize=8, loc="lower right")
    runs = ", ".join(names)
    runs = runs if len(runs) <= 60 else f"{len(names)} runs (named left)"
    fig.suptitle(f"replay, reference vs model per run: {runs}; spline law "
                 f"{laws}", fontsize=11)
    return save_figure(fig, out_dir / "replay_summary.png", figures)
