"""PNG plots of a demo run.

Torque (requested, measured, modelled, reference) with the ±10 % band, and the modelled
front/rear pressure difference P_diff with the actuating and commanded pressure.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutch_ros.offline.demo_summary import BAND, load_series

__all__ = ["plot_demo"]


def plot_demo(bag, profile, started_at: float, out_dir: Path) -> list[Path]:
    """Write ``torque.png`` and ``pressure.png`` into ``out_dir``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    s = load_series(bag, profile, started_at)
    paths = []
    fig, (ax, ax_acc) = plt.subplots(2, 1, figsize=(11, 7), sharex=True,
                                     gridspec_kw={"height_ratios": [3, 1.4]})
    ax.fill_between(s.rig_time, (1 - BAND) * s.request, (1 + BAND) * s.request,
                    color="tab:green", alpha=0.15, label="request ±10 %")
    ax.plot(s.rig_time, s.request, color="k", lw=1.2, label="requested")
    ax.plot(s.rig_time, s.measured, color="tab:blue", lw=0.8, label="measured (rig)")
    ax.plot(s.est_time, s.modelled, color="tab:red", lw=0.9, label="modelled (pack)")
    ax.plot(s.est_time, s.reference, color="tab:orange", lw=0.8, ls="--",
            label="reference (Eq. 1)")
    ax.set_ylabel("torque [N m]")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("clutch demo: closed loop on the simulated rig")
    ratio = np.where(s.settled & (s.request > 0), s.measured / np.maximum(s.request, 1e-9),
                     np.nan)
    ax_acc.axhspan(1 - BAND, 1 + BAND, color="tab:green", alpha=0.15)
    ax_acc.plot(s.rig_time, ratio, color="tab:blue", lw=0.8)
    ax_acc.set_ylim(0.6, 1.4)
    ax_acc.set_ylabel("measured / request")
    ax_acc.set_xlabel("time [s]")
    fig.tight_layout()
    paths.append(Path(out_dir) / "torque.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(11, 4))
    ax.plot(s.rig_time, s.pressure / 1e5, color="k", lw=1.0, label="actuating pressure")
    ax.plot(s.cmd_time, s.cmd_pressure / 1e5, color="tab:purple", lw=0.8, ls="--",
            label="commanded pressure")
    ax.set_ylabel("pressure [bar]")
    ax2 = ax.twinx()
    ax2.plot(s.est_time, s.pressure_difference / 1e5, color="tab:red", lw=0.9,
             label="P_diff modelled (front - rear)")
    ax2.set_ylabel("P_diff [bar]")
    ax.set_xlabel("time [s]")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], loc="upper right", fontsize=8)
    fig.tight_layout()
    paths.append(Path(out_dir) / "pressure.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths
