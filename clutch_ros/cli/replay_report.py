"""PNG report of replayed bags: per bag curves and RMSE bars, per sequence an overview.

Like the thesis's Figs. 55-57: measured vs modelled vs reference (Eq. 1) torque, the torque
accuracy of model and reference with the ±10 % band, the modelled P_diff, and the RMSE of
model and reference side by side (:func:`plot_replay`); and, per bag (sequence), the RMSE and
the share of samples within ±10 % of reference and model (:func:`plot_summary`).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["plot_replay", "plot_summary"]


def plot_replay(bag: Path, rig, batch, out_dir: Path) -> list[Path]:
    """Write ``<bag name>_replay.png`` into ``out_dir``; return the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from clutch_ros.model import rmse

    out_dir.mkdir(parents=True, exist_ok=True)
    t = rig.time
    ok = batch.accepted
    meas = batch.measured_torque
    fig, axes = plt.subplots(4, 1, figsize=(11, 10), sharex=False,
                             gridspec_kw={"height_ratios": [3, 2, 2, 1.6]})
    ax = axes[0]
    ax.plot(t, meas, color="tab:blue", lw=0.8, label="measured")
    ax.plot(t, batch.modelled_torque, color="tab:red", lw=0.9,
            label=f"model ({batch.spline_law})")
    ax.plot(t, batch.reference_torque, color="tab:orange", lw=0.8, ls="--",
            label="reference (Eq. 1)")
    ax.set_ylabel("torque [N m]")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"replay of {Path(bag).name}")
    ax = axes[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        big = np.abs(meas) > 0.05 * np.nanmax(np.abs(meas)) if np.isfinite(meas).any() else ok
        acc_model = np.where(big, meas / batch.modelled_torque, np.nan)
        acc_ref = np.where(big, meas / batch.reference_torque, np.nan)
    ax.axhspan(0.9, 1.1, color="tab:green", alpha=0.15)
    ax.plot(t, acc_ref, color="tab:orange", lw=0.8, label="reference")
    ax.plot(t, acc_model, color="tab:red", lw=0.8, label="model")
    ax.set_ylim(0.6, 1.4)
    ax.set_ylabel("torque accuracy")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[2]
    ax.plot(t, batch.pressure_difference / 1e5, color="tab:red", lw=0.9,
            label="P_diff modelled")
    ax.set_ylabel("P_diff [bar]")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[3]
    values = [rmse(meas[ok], batch.reference_torque[ok]), rmse(meas[ok], batch.modelled_torque[ok])]
    ax.barh(["reference (Eq. 1)", f"model ({batch.spline_law})"], values,
            color=["tab:orange", "tab:red"])
    ax.set_xlabel("RMSE [N m]")
    fig.tight_layout()
    path = out_dir / f"{Path(bag).name}_replay.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def plot_summary(results: list[dict], out_dir: Path) -> Path:
    """Write ``replay_summary.png``: RMSE and within-±10 % per bag, reference vs model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    out_dir.mkdir(parents=True, exist_ok=True)
    names = [Path(r["bag"]).name for r in results]
    y = np.arange(len(results))
    fig, axes = plt.subplots(1, 2, figsize=(12, 1.2 + 0.45 * len(results)), sharey=True)
    for ax, (key, ref_key, label, scale) in zip(axes, (
            ("rmse_nm", "reference_rmse_nm", "RMSE [N m]", 1.0),
            ("within_10pct", "reference_within_10pct", "samples within ±10 % [%]", 100.0))):
        ref = [scale * float(r.get(ref_key, float("nan"))) for r in results]
        model = [scale * float(r[key]) for r in results]
        ax.barh(y + 0.2, ref, height=0.4, color="tab:orange", label="reference (Eq. 1)")
        ax.barh(y - 0.2, model, height=0.4, color="tab:red",
                label=f"model ({results[0]['law']})")
        ax.set_xlabel(label)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, names, fontsize=8)
    axes[0].invert_yaxis()
    axes[1].legend(fontsize=8, loc="lower right")
    fig.suptitle("replay: reference vs model per sequence")
    fig.tight_layout()
    path = out_dir / "replay_summary.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
