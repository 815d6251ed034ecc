"""Validation views of the thesis (§6.5, §2.2.1) as PNG files, for ``clutch replay --report``.

Input: for one or more model labels (e.g. ``"ff_t"``, ``"coulomb"``), the runs replayed
through the estimator as :class:`~clutch_ros.model.identification.RunEvaluation` (see
:func:`~clutch_ros.model.identification.evaluate`, or :func:`evaluation_from_batch` for a
replayed bag's ``EstimateBatch``). Every label must hold the same runs (by name). Output,
written into ``out_dir`` (``<prefix>_*.png``):

- ``rmse.png`` — Fig. 57: torque RMSE [N m] per sequence, reference (Eq. 1 with each model's
  friction law, hatched) against each model.
- ``accuracy_<run>.png`` — Figs. 55–56: torque accuracy (measured / modelled) over time for
  the reference and each model, with the ±10 % band; samples below 5 % of the largest measured
  torque are left out (the ratio is noise there).
- ``pdiff_<run>.png`` — Fig. 54: the measured P_diff (when the run has one) against each
  model's P_diff and the pressure equivalent of its spline force ``Σ_n F_fn / A`` [bar].
- ``xcorr_<run>.png`` — Eq. 3: cross-correlation of the torque residual (measured − modelled)
  with the actuating pressure, normalised, with the 99 % confidence band ±z/√N, for each
  model and the reference; computed on 50 Hz block means over ±2 s (at the full rate the lags
  that matter, hundreds of ms, would need thousands of lags). Bars outside the band mean
  input-dependent dynamics the model misses.

Every title names the run (bag) and the spline law(s), every axis its unit; the run names
under ``rmse.png`` never overlap (:func:`plot_rmse`).

:func:`write_report` returns the written paths and a summary dict (RMSE table, the fraction of
lags outside the band per model and run, the files written per run).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros.errors import ClutchError
from clutch_ros.model.errors import ModelError
from clutch_ros.model.identification import RunEvaluation
from clutch_ros.model.metrics import cross_correlation, rmse
from clutch_ros.offline.plots import fit_category_labels, new_figure, save_figure

__all__ = ["write_report", "plot_rmse", "evaluation_from_batch", "rmse_table", "residual_xcorr"]

DPI = 90  # resolution of the validation PNGs [1/in]


def evaluation_from_batch(name: str, t, batch, measured_pdiff=None):
    """Adapt a replayed bag (``EstimateBatch`` of ``estimate_batch``) to a RunEvaluation."""
    ok = np.asarray(batch.accepted, dtype=bool)
    meas = batch.measured_torque
    return RunEvaluation(
        name=name, law=batch.spline_law, rmse=rmse(meas[ok], batch.modelled_torque[ok]),
        reference_rmse=rmse(meas[ok], batch.reference_torque[ok]),
        t=np.asarray(t, dtype=float)[ok], measured=meas[ok],
        modelled=batch.modelled_torque[ok], reference=batch.reference_torque[ok],
        pressure=batch.actuating_pressure[ok], pressure_difference=batch.pressure_difference[ok],
        spline_force=batch.spline_friction_force[ok],
        measured_pdiff=None if measured_pdiff is None else np.asarray(measured_pdiff)[ok])


def rmse_table(models: Mapping[str, Sequence]) -> dict:
    """``{run: {label: {"model": rmse, "reference": rmse}}}`` [N m]."""
    table: dict = {}
    for label, evals in models.items():
        for ev in evals:
            table.setdefault(ev.name, {})[label] = {"model": ev.rmse,
                                                    "reference": ev.reference_rmse}
    return table


def _block(t, x, rate):
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0 / rate
    m = max(1, int(round(1.0 / (rate * dt))))
    n = (x.size // m) * m
    return x[:n].reshape(-1, m).mean(axis=1), dt * m


def residual_xcorr(ev, modelled, rate: float = 50.0, max_lag_s: float = 2.0):
    """Eq. 3 for ``measured − modelled`` against the pressure on ``rate`` Hz block means.

    Returns ``(lags [s], CrossCorrelation)``.
    """
    keep = np.isfinite(ev.measured) & np.isfinite(modelled)
    res, step = _block(ev.t[keep], (ev.measured - modelled)[keep], rate)
    u, _ = _block(ev.t[keep], ev.pressure[keep], rate)
    lag = int(min(round(max_lag_s / step), max(res.size - 1, 0)))
    cc = cross_correlation(res, u, max_lag=lag)
    return cc.lags * step, cc


def write_report(models: Mapping[str, Sequence], out_dir, prefix: str = "validation",
                 area: float | None = None, *,
                 figures: dict | None = None) -> tuple[list[Path], dict]:
    """Write the four views (module docstring); return (paths, summary).

    ``summary``: ``rmse`` (:func:`rmse_table`), ``xcorr_outside`` (run -> row title ->
    fraction of lags outside the band), ``rmse_file`` (the Fig. 57 PNG) and ``files`` (run ->
    its accuracy, P_diff and cross-correlation PNGs).

    ``models``: label -> list of RunEvaluation (same run names for every label); ``area``:
    piston area [m²] for the spline-force pressure equivalent (default: 3.75e-3, the rig's);
    ``figures``: a dict to keep the saved ``Figure`` objects in, by path (see
    :func:`~clutch_ros.offline.plots.save_figure`). Every title names the run(s) and the
    spline law(s) shown.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = list(models)
    if not labels or not all(models[k] for k in labels):
        raise ClutchError("the validation report needs at least one model with evaluated runs")
    names = [ev.name for ev in models[labels[0]]]
    area = 3.75e-3 if area is None else float(area)
    summary: dict[str, Any] = {"rmse": rmse_table(models), "xcorr_outside": {}, "files": {}}
    paths = [plot_rmse(models, out / f"{prefix}_rmse.png", figures=figures)]
    summary["rmse_file"] = paths[-1]
    for i, name in enumerate(names):
        evs = [(label, models[label][i]) for label in labels if i < len(models[label])]
        laws = _laws_text(evs)
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or f"run{i}"
        paths.append(save_figure(_accuracy_figure(name, laws, evs),
                                 out / f"{prefix}_accuracy_{safe}.png", figures))
        paths.append(save_figure(_pdiff_figure(name, laws, evs, area),
                                 out / f"{prefix}_pdiff_{safe}.png", figures))
        fig, outside = _xcorr_figure(name, laws, evs)
        paths.append(save_figure(fig, out / f"{prefix}_xcorr_{safe}.png", figures))
        summary["xcorr_outside"][name] = outside
        summary["files"][name] = paths[-3:]
    return paths, summary


def _laws_text(evs) -> str:
    """``spline law ff_t`` / ``spline laws none, ff_t`` (the label too where it differs)."""
    laws = [ev.law if label == ev.law else f"{label} ({ev.law})" for label, ev in evs]
    return f"spline law{'s' if len(laws) > 1 else ''} {', '.join(laws)}"


def plot_rmse(models: Mapping[str, Sequence], path, *, figures: dict | None = None) -> Path:
    """Write Fig. 57 to ``path``: torque RMSE [N m] per run, reference (hatched) vs each model.

    ``models`` as for :func:`write_report`; the run names on the x axis never overlap
    (:func:`~clutch_ros.offline.plots.fit_category_labels`).
    """
    labels = list(models)
    names = [ev.name for ev in models[labels[0]]]
    fig = new_figure((min(16.0, max(6.0, 1.5 + 0.9 * len(names) * len(labels))), 4.5), DPI)
    ax = fig.subplots()
    colors = [f"C{j}" for j in range(10)]
    width = 0.8 / (2 * len(labels))
    x = np.arange(len(names))
    for j, label in enumerate(labels):
        evs = {ev.name: ev for ev in models[label]}
        ref = [evs[n].reference_rmse if n in evs else np.nan for n in names]
        mod = [evs[n].rmse if n in evs else np.nan for n in names]
        c = colors[j % len(colors)]
        ax.bar(x + (2 * j) * width - 0.4 + width / 2, ref, width, color="white", edgecolor=c,
               hatch="//", label=f"reference (Eq. 1, {label} friction)")
        ax.bar(x + (2 * j + 1) * width - 0.4 + width / 2, mod, width, color=c,
               label=f"model {label}")
    ax.set_ylabel("torque RMSE [N m]")
    ax.set_xlabel("run (bag name)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    step = fit_category_labels(fig, ax, x, names)
    laws = _laws_text([(label, models[label][0]) for label in labels])
    runs = ", ".join(names)
    if len(runs) > 60 or step > 1:
        runs = f"{len(names)} runs ({'' if step == 1 else f'one in {step} '}named below)"
    fig.suptitle(f"Torque RMSE per run, reference vs model: {runs}; {laws} (thesis Fig. 57)",
                 fontsize=10)
    return save_figure(fig, path, figures)


def _accuracy_figure(name, laws, evs):
    """Figs. 55-56: torque accuracy (measured / modelled) over time, reference and models."""
    fig = new_figure((10, 2.0 * (len(evs) + 1) + 0.6), DPI)
    axes = fig.subplots(len(evs) + 1, 1, sharex=True)
    base = evs[0][1]
    meas = base.measured
    big = np.abs(meas) > 0.05 * np.nanmax(np.abs(meas)) if np.isfinite(meas).any() \
        else np.zeros(meas.shape, dtype=bool)
    rows = [("reference (Eq. 1)", base.t, base.reference)] + [
        (f"model {label}", ev.t, ev.modelled) for label, ev in evs]
    for ax, (title, t, mod) in zip(axes, rows):
        with np.errstate(divide="ignore", invalid="ignore"):
            acc = np.where(big & (np.abs(mod) > 1.0), meas / mod, np.nan)
        ax.axhspan(0.9, 1.1, color="tab:green", alpha=0.15, label="±10 % band")
        ax.plot(t, acc, lw=0.8, label="measured / modelled torque")
        ax.set_ylim(0.6, 1.4)
        ax.set_ylabel("accuracy [-]")
        ax.set_title(title, fontsize=9)
    axes[0].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{name}, {laws}: torque accuracy (thesis Figs. 55-56)", fontsize=11)
    return fig


def _pdiff_figure(name, laws, evs, area):
    """Fig. 54: measured and modelled P_diff and the spline force's pressure equivalent."""
    fig = new_figure((10, 2.4 * len(evs) + 1.0), DPI)
    axes = fig.subplots(len(evs), 1, sharex=True, squeeze=False)
    for ax, (label, ev) in zip(axes[:, 0], evs):
        if ev.measured_pdiff is not None:
            ax.plot(ev.t, ev.measured_pdiff / 1e5, color="tab:gray", lw=0.7,
                    label="P_diff measured\n(FlexiForce, calibrated\nagainst F_act)")
        ax.plot(ev.t, ev.pressure_difference / 1e5, color="tab:red", lw=0.9,
                label="P_diff model")
        spline = np.asarray(ev.spline_force)
        if spline.ndim == 2 and spline.size:
            ax.plot(ev.t, np.nansum(spline, axis=1) / area / 1e5, color="tab:blue",
                    lw=0.9, ls="--", label="spline force sum / A")
        ax.set_ylabel("pressure [bar]")
        ax.set_title(f"model {label}", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"{name}, {laws}: P_diff and the spline force (thesis Fig. 54)", fontsize=11)
    return fig


def _xcorr_figure(name, laws, evs):
    """Eq. 3: residual-pressure cross-correlation with its band; also the outside fractions."""
    fig = new_figure((8, 1.9 * (len(evs) + 1) + 0.6), DPI)
    axes = fig.subplots(len(evs) + 1, 1, sharex=True)
    base = evs[0][1]
    rows = [("reference (Eq. 1)", base, base.reference)] + [
        (f"model {label}", ev, ev.modelled) for label, ev in evs]
    outside = {}
    for ax, (title, ev, mod) in zip(axes, rows):
        ax.set_ylabel("R / (σε σu) [-]")
        try:
            lags, cc = residual_xcorr(ev, mod)
        except ModelError as err:  # too short a run: say so in the plot
            ax.set_title(f"{title}: {err}", fontsize=8)
            continue
        ax.vlines(lags, 0.0, cc.normalized, lw=1.0)
        ax.axhspan(-cc.band_normalized, cc.band_normalized, color="tab:green", alpha=0.2)
        ax.set_title(f"{title}: {100 * cc.outside:.0f} % of lags outside the "
                     f"{100 * cc.confidence:.0f} % band", fontsize=9)
        outside[title] = cc.outside
    axes[-1].set_xlabel("lag τ [s] (residual lags the pressure for τ > 0)")
    fig.suptitle(f"{name}, {laws}:\nresidual-pressure cross-correlation (Eq. 3)", fontsize=11)
    return fig, outside
