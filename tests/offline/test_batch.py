"""Parallel offline work: ``clutch replay --jobs N`` / ``--cluster ADDRESS`` and fit's reads.

The golden bags (simulated Table 3 runs, real MCAP bags) are replayed serially, by two local
worker processes and on a Dask scheduler started by the test (``distributed.LocalCluster``
bound to 127.0.0.1, its workers in this process, reached over TCP); every figure of every
bag's summary must be the same (timings aside) and in input order, and the ClutchEstimate
bags written must hold the same columns. Errors of a job in a worker come back as the job's
one-line message.
"""

import contextlib
import gc
import io
import json
import subprocess
import sys
import time

import numpy as np
import pytest
from distributed import LocalCluster

from clutch_ros.bag.arrays import read_columns
from clutch_ros.bag.rig_states import read_rig_states
from clutch_ros.cli import main as clutch_main
from clutch_ros.offline import batch
from clutch_ros.offline.batch import BatchJobError, ClusterError, run_jobs
from clutch_ros.offline.flexiforce import load_runs
from tests.conftest import REPO

GOLDEN = REPO / "tests" / "data" / "golden" / "bags"
BAGS = [GOLDEN / name for name in ("table3_seq2_10rpm", "table3_seq1_30rpm",
                                   "table3_seq4_10rpm", "table3_seq3_30rpm")]
#: summary keys that are wall times (differ from run to run) or say how the work was
#: scheduled (a serial replay streams, a pool worker does not), not what it computed
TIMINGS = {"seconds", "samples_per_s", "read_s", "estimate_s", "streamed", "streamed_pieces"}


def replay_json(*args) -> list[dict]:
    """Run ``clutch replay`` in this process; return its JSON list without the timings."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = clutch_main(["replay", *map(str, BAGS), "--params", "flexiforce_8", "--json",
                            *map(str, args)])
    assert code == 0
    return [{k: v for k, v in r.items() if k not in TIMINGS} for r in json.loads(out.getvalue())]


@pytest.fixture(scope="module")
def serial():
    """Return the serial run's summaries."""
    return replay_json()


@pytest.fixture(scope="module")
def cluster():
    """Start a Dask scheduler, two in-process workers, on 127.0.0.1 (TCP); its address."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  protocol="tcp", host="127.0.0.1",
                                  dashboard_address=None) as local:
        yield local.scheduler_address


def test_serial_summaries_are_per_bag_in_order(serial):
    assert [r["bag"] for r in serial] == [str(b) for b in BAGS]
    assert all(r["samples"] > 500 and np.isfinite(r["rmse_nm"]) for r in serial)
    # the four runs differ, so an order mix-up cannot go unnoticed
    assert len({r["rmse_nm"] for r in serial}) == len(BAGS)


def test_jobs_2_gives_the_serial_figures(serial):
    assert replay_json("--jobs", "2") == serial


def test_cluster_gives_the_serial_figures(serial, cluster):
    assert cluster.startswith("tcp://127.0.0.1:")
    assert replay_json("--cluster", cluster) == serial


def test_parallel_outputs_equal_serial_outputs(tmp_path, cluster):
    """-o with --jobs 2 and --cluster writes the same ClutchEstimate columns as serially."""
    outs = {}
    for label, extra in (("serial", []), ("jobs", ["--jobs", "2"]),
                         ("cluster", ["--cluster", cluster])):
        replay_json("-o", tmp_path / label, *extra)
        outs[label] = {b.name: read_columns(tmp_path / label / b.name, "/clutch_estimate")[0]
                       for b in BAGS}
    for label in ("jobs", "cluster"):
        for name, cols in outs["serial"].items():
            other = outs[label][name]
            assert cols.keys() == other.keys()
            for key, values in cols.items():
                np.testing.assert_array_equal(other[key], values, err_msg=f"{label} {name} {key}")


def test_fit_reads_the_same_runs_in_parallel(cluster):
    area = 3.75e-3  # piston area [m^2]; only scales the FlexiForce calibration's force
    serial_runs, serial_info = load_runs(BAGS[:3], area)
    for kwargs in ({"jobs": 2}, {"cluster": cluster}):
        runs, info = load_runs(BAGS[:3], area, **kwargs)
        assert [r.name for r in runs] == [r.name for r in serial_runs]
        for a, b in zip(runs, serial_runs):
            for field in ("t", "pressure", "temperature", "slip_speed", "torque",
                          "front_pressure", "rear_pressure"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        cal, ref = info["calibration"], serial_info["calibration"]
        assert (cal is None) == (ref is None)
        assert ref is None or cal.to_dict() == ref.to_dict()
        assert info["calibration_error"] == serial_info["calibration_error"]


def test_run_jobs_keeps_input_order_and_values():
    items = [BAGS[3], BAGS[0], BAGS[2]]
    lengths = run_jobs(_length, items, jobs=2)
    assert lengths == [len(read_rig_states(b)) for b in items]
    assert len(set(lengths)) == 3
    # the objects alive at the fork were moved out of the collector's view (batch.py)
    assert gc.get_freeze_count() > 0


def _length(bag) -> int:
    return len(read_rig_states(bag))


def _started(item) -> tuple[int, int]:
    """Return ``(item, start time [ns])`` of a job, after a pause that lets both workers start."""
    start = time.monotonic_ns()
    time.sleep(0.5)
    return item, start


def test_dispatch_order_is_largest_first_with_ties_in_input_order():
    assert batch.dispatch_order(None, 3) == [0, 1, 2]
    assert batch.dispatch_order([10, 30, 20, 30], 4) == [1, 3, 2, 0]
    with pytest.raises(ValueError, match="costs has 2 values for 3 items"):
        batch.dispatch_order([1, 2], 3)


def test_costs_start_the_largest_item_first_and_keep_input_order():
    """Two workers take the items in cost order; the results come back in input order."""
    items = [0, 1, 2, 3]
    out = run_jobs(_started, items, jobs=2, costs=[1.0, 4.0, 2.0, 3.0])
    assert [item for item, _ in out] == items
    starts = {item: start for item, start in out}
    # two workers take 1 and 3 first, then 2 and 0: 0 (the smallest) starts after 1 and 3
    assert starts[0] > max(starts[1], starts[3])
    assert starts[2] > min(starts[1], starts[3])


def test_replay_with_unequal_bags_gives_the_serial_figures_in_order(serial):
    """--jobs hands the bags out largest first; the summaries still follow the command line."""
    sizes = [sum(f.stat().st_size for f in b.iterdir()) for b in BAGS]
    assert len(set(sizes)) > 1  # unequal, so the dispatch order differs from the input order
    assert batch.dispatch_order(sizes, len(BAGS)) != list(range(len(BAGS)))
    assert replay_json("--jobs", "3") == serial


def test_a_failing_job_reports_its_message(tmp_path, cluster):
    missing = tmp_path / "no_such_bag"
    for kwargs in ({"jobs": 2}, {"cluster": cluster}):
        with pytest.raises(BatchJobError, match="no_such_bag"):
            run_jobs(_length, [BAGS[0], missing], **kwargs)


def test_unreachable_scheduler_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(batch, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(ClusterError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        run_jobs(_length, BAGS[:2], cluster="tcp://127.0.0.1:9")


@pytest.mark.parametrize("args, message", [
    (["--jobs", "0"], "--jobs must be >= 1"),
    (["--jobs", "2"], "no_such_bag"),
])
def test_cli_bad_batch_input_is_one_line(tmp_path, args, message):
    proc = subprocess.run(
        [sys.executable, "-m", "clutch_ros.cli", "replay", str(BAGS[0]),
         str(tmp_path / "no_such_bag"), "--params", "flexiforce_8", *args],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


def fit_json(tmp_path, *args) -> dict:
    """Run ``clutch fit --law none`` on two golden bags in this process; return its JSON."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = clutch_main(["fit", *map(str, BAGS[:2]), "--law", "none", "--max-seconds", "0",
                            "-o", str(tmp_path / f"fit{len(args)}.yaml"), "--json",
                            *map(str, args)])
    assert code == 0
    return json.loads(out.getvalue())


def test_fit_with_jobs_and_cluster_gives_the_serial_fit(tmp_path, cluster):
    serial = fit_json(tmp_path)
    assert serial["rmse"] > 0 and serial["values"]
    for args in (("--jobs", "2"), ("--cluster", cluster)):
        doc = fit_json(tmp_path, *args)
        for key in ("values", "stderr", "rmse", "run_rmse", "evaluations"):
            assert doc[key] == serial[key], (args, key)
