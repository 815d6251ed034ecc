"""PNG plots of a demo run, and the figure helpers every report PNG uses.

Demo: torque (requested, measured, modelled, reference) with the ±10 % band, and the modelled
front/rear pressure difference P_diff with the actuating and commanded pressure.

Helpers (:func:`new_figure`, :func:`save_figure`, :func:`fit_category_labels`): figures are
plain Agg-backed matplotlib ``Figure`` objects with constrained layout (no pyplot state, so
nothing to close and nothing leaks between runs), created at the resolution they are saved
with, so the layout a test inspects after :func:`save_figure` is the one in the PNG.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from clutch_ros.bag.reader import BagReader
from clutch_ros.interfaces import CLUTCH_ESTIMATE
from clutch_ros.offline.demo_summary import BAND, load_series

__all__ = ["plot_demo", "new_figure", "save_figure", "fit_category_labels", "demo_run_name"]

_BREAK = re.compile(r"(?<=[_\-. ])")  # wrap run names after these characters


def new_figure(figsize: tuple[float, float], dpi: float = 100.0):
    """Return an Agg-backed ``Figure`` (size [in], ``dpi`` [1/in]) with constrained layout."""
    # matplotlib takes ~0.5 s to import: only commands that plot pay for it.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: Path, figures: dict | None = None) -> Path:
    """Save ``fig`` as PNG at its own dpi; keep it in ``figures[path]`` if a dict is given."""
    path = Path(path)
    fig.savefig(path, dpi="figure")
    if figures is not None:
        figures[path] = fig
    return path


def _wrap(name: str, width: int) -> str:
    """Break ``name`` after ``_``, ``-``, ``.`` or blanks into lines of about ``width`` chars."""
    lines, line = [], ""
    for part in _BREAK.split(name):
        if line and len(line) + len(part) > width:
            lines.append(line)
            line = ""
        line += part
    return "\n".join(lines + [line])


def _overlap(fig, texts) -> bool:
    """Tell whether two visible ``texts`` overlap (window extents) or one leaves the figure."""
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in texts if t.get_visible() and t.get_text()]
    inside = fig.bbox.padded(1.0)
    if any(not (inside.contains(b.x0, b.y0) and inside.contains(b.x1, b.y1)) for b in boxes):
        return True
    boxes.sort(key=lambda b: b.x0)
    return any(a.padded(1.0).overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])


def fit_category_labels(fig, ax, positions, names, fontsize: float = 8.0) -> int:
    """Label the x ticks ``positions`` with ``names`` so that no two labels overlap.

    Tries in turn, measuring the rendered labels each time: horizontal labels wrapped at
    ``_``/``-``/``.`` (8 pt, then 7 pt); vertical labels wrapped likewise; vertical labels on
    one line (8, 7, 6 pt); finally every k-th label at 7 pt (the other ticks stay
    unlabelled). The figure then grows by the height of the label band, so the plot keeps
    its height. Returns k: 1 when every name is shown.
    """
    positions = np.asarray(positions, dtype=float)
    attempts = [[(0, _wrap(n, 14), size) for n in names] for size in (fontsize, 7.0)]
    attempts.append([(90, _wrap(n, 26), fontsize) for n in names])
    attempts += [[(90, n, size) for n in names] for size in (fontsize, 7.0, 6.0)]
    steps = [1] * len(attempts) + list(range(2, len(names) + 1))
    attempts += [[(90, n if i % step == 0 else "", 7.0) for i, n in enumerate(names)]
                 for step in steps[len(attempts):]]
    height = fig.get_figheight()
    fig.set_figheight(height + 10.0)  # room for any label band while measuring
    chosen = steps[-1]
    for step, labels in zip(steps, attempts):
        _set_labels(ax, positions, labels)
        if not _overlap(fig, ax.get_xticklabels()):
            chosen = step
            break
    renderer = fig.canvas.get_renderer()
    band = max((t.get_window_extent(renderer).height for t in ax.get_xticklabels()
                if t.get_text()), default=0.0) / fig.dpi
    fig.set_figheight(np.ceil((height + band) * fig.dpi) / fig.dpi)  # whole pixels
    return chosen


def _set_labels(ax, positions, labels) -> None:
    """Set the x tick labels ``[(rotation [deg], text, font size [pt]), ...]``."""
    rotation, _, size = labels[0]
    ax.set_xticks(positions, [n for _, n, _ in labels], rotation=rotation, fontsize=size,
                  ha="center", va="top")


def demo_run_name(bag) -> str:
    """Return the run a demo bag belongs to: its run directory's name for ``<run>/bag``."""
    bag = Path(bag).resolve()
    return bag.parent.name if bag.name == "bag" else bag.name


def _recorded_law(bag) -> str:
    """Return the estimator's spline law as recorded in the first ClutchEstimate."""
    with BagReader(bag) as reader:
        for _, _, msg in reader.messages([CLUTCH_ESTIMATE.absolute]):
            return msg.spline_law or "unknown"
    return "unknown (no estimates recorded)"


def plot_demo(bag, profile, started_at: float, out_dir: Path, *,
              figures: dict | None = None) -> list[Path]:
    """Write ``torque.png`` and ``pressure.png`` into ``out_dir``; return their paths.

    Titles name the run (:func:`demo_run_name`) and the estimator's spline law (read from the
    bag). ``figures``: see :func:`save_figure`.
    """
    s = load_series(bag, profile, started_at)
    what = f"{demo_run_name(bag)}, estimator spline law {_recorded_law(bag)}"
    paths = []
    fig = new_figure((11, 7), dpi=110)
    ax, ax_acc = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1.4]})
    ax.fill_between(s.rig_time, (1 - BAND) * s.request, (1 + BAND) * s.request,
                    color="tab:green", alpha=0.15, label="request ±10 %")
    ax.plot(s.rig_time, s.request, color="k", lw=1.2, label="requested")
    ax.plot(s.rig_time, s.measured, color="tab:blue", lw=0.8, label="measured (rig)")
    ax.plot(s.est_time, s.modelled, color="tab:red", lw=0.9, label="modelled (pack)")
    ax.plot(s.est_time, s.reference, color="tab:orange", lw=0.8, ls="--",
            label="reference (Eq. 1)")
    ax.set_ylabel("torque [N m]")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("torque: closed loop on the simulated rig", fontsize=10)
    ratio = np.where(s.settled & (s.request > 0), s.measured / np.maximum(s.request, 1e-9),
                     np.nan)
    ax_acc.axhspan(1 - BAND, 1 + BAND, color="tab:green", alpha=0.15)
    ax_acc.plot(s.rig_time, ratio, color="tab:blue", lw=0.8)
    ax_acc.set_ylim(0.6, 1.4)
    ax_acc.set_ylabel("measured / request [-]")
    ax_acc.set_xlabel("time since the profile start [s]")
    fig.suptitle(f"clutch demo {what}")
    paths.append(save_figure(fig, Path(out_dir) / "torque.png", figures))

    fig = new_figure((11, 4), dpi=110)
    ax = fig.subplots()
    ax.plot(s.rig_time, s.pressure / 1e5, color="k", lw=1.0, label="actuating pressure")
    ax.plot(s.cmd_time, s.cmd_pressure / 1e5, color="tab:purple", lw=0.8, ls="--",
            label="commanded pressure")
    ax.set_ylabel("pressure [bar]")
    ax2 = ax.twinx()
    ax2.plot(s.est_time, s.pressure_difference / 1e5, color="tab:red", lw=0.9,
             label="P_diff modelled (front - rear)")
    ax2.set_ylabel("P_diff [bar]")
    ax.set_xlabel("time since the profile start [s]")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], loc="upper right", fontsize=8)
    fig.suptitle(f"clutch demo {what}: pressures")
    paths.append(save_figure(fig, Path(out_dir) / "pressure.png", figures))
    return paths
