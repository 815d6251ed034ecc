"""The report PNGs read well: run names never overlap, every axis has a unit, titles say what.

Each report is rendered for golden bags (``tests/data/golden/bags``) into ``tmp_path`` by the
code path the commands use (``ReplayReport`` for ``clutch replay --report``, ``plot_demo`` for
``clutch demo``), with ``figures=`` keeping the saved ``Figure`` objects; the assertions read
those objects after saving (rendered text extents, labels, titles), not the pixels:

- no two x tick labels of the validation RMSE bar chart (``plot_rmse``, which ``write_report``
  calls) overlap (window extents, as drawn at
  the PNG's resolution) and none leaves the figure, with 12 and 40 long run names;
- every axis a reader sees values on has a label with a unit in brackets ([N m], [bar], [s],
  [-] for dimensionless...), or is a category axis with a name; an axis whose tick labels are
  hidden shares its scale with a labelled one (stacked time plots, twin axes);
- every figure's titles name its run (bag) and spline law; a figure of many runs names them in
  its title or on its category axis.
"""

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.typestore import (
    CLUTCH_ESTIMATE_TYPE,
    PRESSURE_COMMAND_TYPE,
    RIG_STATE_TYPE,
    pressure_command_msg,
)
from clutch_ros.bag.writer import BagWriter
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.offline.plots import plot_demo
from clutch_ros.offline.replay import replay_bag, write_estimates
from clutch_ros.offline.replay_report import ReplayReport
from clutch_ros.offline.validation_report import evaluation_from_batch, plot_rmse
from clutch_ros.rig.request_profile import demo_profile

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden" / "bags"
BAGS = ("table3_seq2_10rpm", "table3_seq3_10rpm")
UNIT = re.compile(r"[\[(](N m|bar|Pa|rad/s|rpm|s|°C|-|%)[\])]")


@pytest.fixture(scope="module")
def params():
    return load_params(preset_path("flexiforce_8"))


@pytest.fixture(scope="module")
def replayed(params):
    return [replay_bag(GOLDEN / name, params) for name in BAGS]


def _numeric(text: str) -> bool:
    try:
        float(text.replace("\u2212", "-"))
    except ValueError:
        return False
    return True


def _shown(ax, which):
    """Return the tick label texts of ``ax``'s ``which`` axis a reader sees."""
    axis = ax.xaxis if which == "x" else ax.yaxis
    if not axis.get_visible():
        return []
    return [t.get_text() for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]


def _label_problem(ax, which):
    """None if ``ax``'s ``which`` axis is labelled as the module docstring says, else why."""
    label = ax.get_xlabel() if which == "x" else ax.get_ylabel()
    ticks = _shown(ax, which)
    if not ticks:  # hidden tick labels: the scale must be labelled on a shared axes
        shared = ax.get_shared_x_axes() if which == "x" else ax.get_shared_y_axes()
        if any(_shown(o, which) and _label_problem(o, which) is None
               for o in shared.get_siblings(ax) if o is not ax):
            return None
        return f"{which} axis without tick labels and no labelled shared axis"
    if not label.strip():
        return f"empty {which}label (ticks {ticks[:3]})"
    if all(_numeric(t) for t in ticks) and not UNIT.search(label):
        return f"{which}label {label!r} has no unit"
    return None


def _titles(fig) -> str:
    return " ".join([fig.get_suptitle()] + [ax.get_title() for ax in fig.axes])


def _check_figure(path, fig, runs, law):
    """Axis labels with units; titles with run(s) and law; the PNG on disk is this figure."""
    fig.draw_without_rendering()
    assert path.is_file() and path.read_bytes()[:4] == b"\x89PNG", path
    png = path.read_bytes()
    size = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    np.testing.assert_allclose(size, fig.get_size_inches() * fig.dpi, atol=1.0,  # whole px
                               err_msg=str(path))
    for ax in fig.axes:
        for which in "xy":
            problem = _label_problem(ax, which)
            assert problem is None, f"{path.name}: {problem}"
    titles = _titles(fig)
    assert law in titles, f"{path.name}: law {law!r} not in {titles!r}"
    on_axes = {"".join(t.split("\n")) for ax in fig.axes for w in "xy" for t in _shown(ax, w)}
    for run in runs:
        assert run in titles or run in on_axes, f"{path.name}: run {run!r} not named"


def _suptitle(fig):
    return next(t for t in fig.texts if t.get_text() == fig.get_suptitle())


def _tick_boxes(fig, ax):
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    return [(t.get_text(), t.get_window_extent(renderer)) for t in ax.get_xticklabels()
            if t.get_visible() and t.get_text()]


def test_replay_report_figures(params, replayed, tmp_path):
    figures = {}
    report = ReplayReport(tmp_path / "report", params, params.spline.law, figures=figures)
    summaries = []
    for result in replayed:
        summaries.append(dict(result.summary, plots=report.add(result)))
    report.finish(summaries)
    written = {Path(p) for s in summaries for p in s["plots"]}
    assert written == set(figures)  # every PNG written is a figure checked here
    assert len(written) == 2 + 1 + 1 + 3 * 2  # replay x2, summary, RMSE, 3 views x2
    law = params.spline.law
    for path, fig in figures.items():
        runs = [b for b in BAGS if b in path.name] or list(BAGS)  # overviews: every run
        _check_figure(path, fig, runs, law)


def _long_named(evaluation, count):
    """``count`` copies of ``evaluation`` with long distinct names and distinct RMSEs."""
    return [replace(evaluation, name=f"rig2_2026-11-21_table3_seq{i % 5 + 1}_incremented_"
                    f"step_10rpm_run{i:02d}", rmse=evaluation.rmse * (1 + 0.05 * i))
            for i in range(count)]


@pytest.mark.parametrize("count,laws", [(12, ("ff_t",)), (12, ("ff_t", "coulomb")),
                                        (40, ("ff_t",)), (150, ("ff_t",))])
def test_rmse_bar_chart_labels_never_overlap(replayed, tmp_path, count, laws):
    result = replayed[0]
    base = evaluation_from_batch(BAGS[0], result.rig.time, result.batch)
    models = {law: [replace(ev, law=law) for ev in _long_named(base, count)] for law in laws}
    names = [ev.name for ev in models[laws[0]]]
    figures = {}
    path = plot_rmse(models, tmp_path / "rmse.png", figures=figures)
    fig = figures[path]
    (ax,) = fig.axes
    boxes = _tick_boxes(fig, ax)
    shown = ["".join(text.split("\n")) for text, _ in boxes]
    if count <= 40:  # up to 40 long names fit on the chart: every one is shown, in order
        assert shown == names
    else:  # 150 are thinned to every k-th name, k as small as fits, in order
        step = names.index(shown[1])
        assert shown == names[::step] and 2 <= step <= 4
        assert f"150 runs (one in {step} named below)" in fig.get_suptitle()
        names = shown  # the runs the figure names
    figure_box = fig.bbox
    renderer = fig.canvas.get_renderer()
    titles = [("xlabel", ax.xaxis.label), ("ylabel", ax.yaxis.label),
              ("suptitle", _suptitle(fig)), ("legend", ax.get_legend())]
    for i, (text, box) in enumerate(boxes):
        for other, obox in boxes[i + 1:]:
            assert not box.overlaps(obox), f"{text!r} overlaps {other!r}"
        for what, artist in titles:
            assert not box.overlaps(artist.get_window_extent(renderer)), f"{text!r}, {what}"
    for text, box in boxes + [(w, a.get_window_extent(renderer)) for w, a in titles]:
        assert figure_box.x0 <= box.x0 and box.x1 <= figure_box.x1, f"{text!r} cut off"
        assert figure_box.y0 <= box.y0 and box.y1 <= figure_box.y1, f"{text!r} cut off"
    # the labels do not squash the plot: it keeps at least 2.5 in of height
    assert ax.get_window_extent(renderer).height / fig.dpi >= 2.5
    for law in laws:
        _check_figure(path, fig, names, law)


def _demo_like_bag(result, bag: Path, tmp_path: Path) -> None:
    """Write a bag as ``clutch demo`` records it, from a golden bag and its replay.

    ``/rig_state`` copied from the golden bag, ``/clutch_estimate`` the replay's
    (``write_estimates``), ``/pressure_command`` the rig's actuating pressure at 10 Hz.
    """
    estimates = tmp_path / "estimates"
    write_estimates(estimates, result)
    bag.parent.mkdir(parents=True)
    with BagWriter(bag) as writer:
        rig_topic = writer.add_topic("/rig_state", RIG_STATE_TYPE)
        est_topic = writer.add_topic("/clutch_estimate", CLUTCH_ESTIMATE_TYPE)
        cmd_topic = writer.add_topic("/pressure_command", PRESSURE_COMMAND_TYPE)
        with BagReader(result.bag) as reader:
            for _, stamp, msg in reader.messages(["/rig_state"]):
                writer.write(rig_topic, stamp, msg)
        with BagReader(estimates) as reader:
            for _, stamp, msg in reader.messages(["/clutch_estimate"]):
                writer.write(est_topic, stamp, msg)
        rig = result.rig
        for stamp, pressure in zip(rig.stamp_ns[::10], rig.actuating_pressure[::10]):
            writer.write(cmd_topic, int(stamp), pressure_command_msg(int(stamp),
                                                                     pressure=float(pressure)))


def test_demo_figures(params, replayed, tmp_path):
    result = replayed[1]
    bag = tmp_path / "demo-20261121-101500" / "bag"
    _demo_like_bag(result, bag, tmp_path)
    profile = demo_profile(300.0, quick=True)
    figures = {}
    paths = plot_demo(bag, profile, float(result.rig.stamp_ns[0]) * 1e-9, bag.parent,
                      figures=figures)
    assert [p.name for p in paths] == ["torque.png", "pressure.png"]
    assert set(figures) == set(paths)
    for path, fig in figures.items():
        _check_figure(path, fig, ["demo-20261121-101500"], params.spline.law)
