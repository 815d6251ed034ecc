"""Simulated rig runs as RigState bags: the golden regression data and round-trip tests.

:func:`simulate_run` drives the simulated rig's truth plant (``params/rig_truth.yaml``, its
own parameters, never the estimator's) through a scenario offline, without any bus
(:func:`clutch_ros.rig.scenario.run_offline`, 1 kHz), and keeps every ``step``-th sample
(decimation to ``rate_hz``, e.g. 100 Hz). :func:`write_run` writes it as a ``RigState`` bag
with bag timestamp = header stamp = ``start_ns`` + simulation time, as ``clutch import``
does. :data:`GOLDEN_RUNS` names the thesis sequences: Table 3 (1-5 at 10 and 30 rpm, DBP)
and Table 4 (1-4, PBD).

Scripted runs have no torque request: ``torque_request`` is 0 N m there (the message's "0
when none"). Wheel speeds are optional (``wheel_speeds=False`` leaves them empty: the
FlexiForce rig has a locked output shaft and no vehicle).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros import interfaces, rigstate
from clutch_ros.bag.arrays import TemplateSerializer, write_columns
from clutch_ros.bag.typestore import RIG_STATE_TYPE
from clutch_ros.bag.writer import BagWriter
from clutch_ros.errors import ConfigError
from clutch_ros.rig.plant import RigPlant
from clutch_ros.rig.scenario import table3_run, table4_run
from clutch_ros.rig.simulator import run_offline

__all__ = ["GOLDEN_RUNS", "START_NS", "RigRun", "golden_scenario", "simulate_run", "write_run"]

#: Stamp of simulation time 0 of every generated run [ns since epoch] (2023-11-14).
START_NS = 1_700_000_000 * 1_000_000_000

#: RigState scalar and flag fields copied from the plant's signals (same names).
SCALARS = (*rigstate.SCALARS, "has_measured_torque")

#: Golden run name -> (table, sequence, slip rpm or None for Table 4, plant noise seed).
GOLDEN_RUNS: dict[str, tuple[int, int, float | None, int]] = {
    **{
        f"table3_seq{seq}_{rpm}rpm": (3, seq, float(rpm), 100 + 10 * seq + rpm // 10)
        for rpm in (10, 30)
        for seq in range(1, 6)
    },
    **{f"table4_seq{seq}": (4, seq, None, 200 + seq) for seq in range(1, 5)},
}


def golden_scenario(name: str) -> tuple[Any, int]:
    """Return ``(scenario, seed)`` of a :data:`GOLDEN_RUNS` entry."""
    try:
        table, seq, rpm, seed = GOLDEN_RUNS[name]
    except KeyError:
        raise ConfigError(f"unknown golden run {name!r}; known: {', '.join(GOLDEN_RUNS)}") from None
    if table == 3:
        assert rpm is not None  # every Table 3 run has its slip speed
        scenario: Any = table3_run(seq, rpm)
    else:
        scenario = table4_run(seq)
    return scenario, seed


@dataclass
class RigRun:
    """A decimated simulated run.

    Attributes:
        name: scenario name.
        stamp_ns: sample stamps [ns since epoch] (int64).
        columns: RigState fields (SI; ``ff_voltages`` (n, 8) [V], ``wheel_speeds`` (n, 4)
            [rad/s] or (n, 0)).
        truth: the plant's noise-free signals at the same samples (``true_torque`` [N m],
            ``pressure_difference`` [Pa] ...), for tests.
        seed: plant noise seed.
        rate_hz: sample rate [Hz].

    """

    name: str
    stamp_ns: np.ndarray
    columns: dict[str, np.ndarray]
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    seed: int = 0
    rate_hz: float = 100.0

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @property
    def time(self) -> np.ndarray:
        """Simulation time of each sample [s]."""
        return (self.stamp_ns - START_NS) / 1e9


def simulate_run(
    scenario: Any,
    *,
    seed: int = 0,
    rate_hz: float = 100.0,
    sim_dt: float = 1e-3,
    start_ns: int = START_NS,
    plant: str = "rig_truth",
    wheel_speeds: bool = True,
    duration: float | None = None,
) -> RigRun:
    """Run the truth plant through ``scenario`` at ``1/sim_dt`` and decimate to ``rate_hz``.

    Args:
        scenario: a :class:`clutch_ros.rig.scenario.Scenario` (scripted).
        seed: plant noise seed.
        rate_hz: output sample rate [Hz]; ``1 / (sim_dt * rate_hz)`` must be an integer.
        sim_dt: plant step [s].
        start_ns: stamp of simulation time 0 [ns since epoch].
        plant: truth parameter preset or file.
        wheel_speeds: keep the wheel speeds (else empty).
        duration: simulated time [s] (default: the scenario's).

    """
    ratio = 1.0 / (sim_dt * rate_hz)
    step = int(round(ratio))
    if step < 1 or abs(ratio - step) > 1e-9:
        raise ConfigError(f"rate {rate_hz} Hz is not an integer divisor of 1/{sim_dt} s")
    signals = run_offline(RigPlant.from_file(plant, seed=seed), scenario, sim_dt, duration)
    rows = np.arange(step - 1, len(signals["time"]), step)
    t = signals["time"][rows]
    stamps = start_ns + np.round(t * 1e9).astype(np.int64)
    cols = {name: np.asarray(signals[name][rows]) for name in SCALARS}
    cols["torque_request"] = np.nan_to_num(cols["torque_request"], nan=0.0)
    cols["ff_voltages"] = np.asarray(signals["ff_voltages"][rows], dtype=float)
    wheels = np.asarray(signals["wheel_speeds"][rows], dtype=float)
    cols["wheel_speeds"] = wheels if wheel_speeds else np.zeros((len(rows), 0))
    truth = {
        k: np.asarray(signals[k][rows])
        for k in ("true_torque", "true_actuating_pressure", "pressure_difference", "mu")
    }
    return RigRun(getattr(scenario, "name", "run"), stamps, cols, truth, seed, rate_hz)


def write_run(
    path: str | Path,
    run: RigRun,
    *,
    storage: str = "mcap",
    compression: str = "none",
    frame_id: str = "rig",
    custom_data: Mapping[str, str] | None = None,
    transform: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None,
) -> BagWriter:
    """Write ``run`` as a RigState bag on ``/rig_state`` (bag time = header stamp).

    Args:
        path: bag directory to create.
        run: the run.
        storage: ``mcap`` or ``sqlite3``.
        compression: ``none`` or ``zstd`` (MCAP chunks).
        frame_id: header frame id.
        custom_data: extra ``metadata.yaml`` custom data (the run name, seed and rate are
            always stored).
        transform: optional edit of the columns before writing (tests inject bad samples).

    Returns:
        the closed writer.

    """
    cols = dict(run.columns)
    if transform is not None:
        cols = transform(cols)
    ff = cols["ff_voltages"].shape[1]
    wheels = cols["wheel_speeds"].shape[1]
    serializer = TemplateSerializer(
        RIG_STATE_TYPE, frame_id=frame_id, ff_voltages=np.zeros(ff), wheel_speeds=np.zeros(wheels)
    )
    if wheels == 0:
        cols.pop("wheel_speeds")
    if ff == 0:
        cols.pop("ff_voltages")
    custom = {
        "clutch_ros.source": f"simulated rig: {run.name}",
        "clutch_ros.seed": str(run.seed),
        "clutch_ros.rate_hz": f"{run.rate_hz:g}",
        **dict(custom_data or {}),
    }
    writer = BagWriter(
        path, storage=storage, compression=compression, custom_data=custom, delete_on_error=True
    )
    with writer:
        topic = writer.add_topic(interfaces.RIG_STATE.absolute)
        write_columns(writer, topic, serializer, run.stamp_ns, cols)
    return writer
