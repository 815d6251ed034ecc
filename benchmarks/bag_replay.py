"""Read-throughput benchmark on a generated one-hour 1 kHz RigState bag.

``python -m benchmarks.bag_replay [--seconds 3600] [--rate 1000] [--storage mcap] [--json]``

1. Generates ``seconds * rate`` RigState messages (3.6 M for the default hour) of a
   synthetic rig run into a temporary bag. Generation serializes one template message and
   patches the fields of whole blocks of messages with numpy (no per-message Python objects),
   then writes them through :class:`~clutch_ros.bag.writer.BagWriter`.
2. Measures, on that bag, in the same run:
   - bare rosbags: ``Reader.messages()`` + ``Typestore.deserialize_cdr`` per message;
   - :meth:`~clutch_ros.bag.reader.BagReader.messages` (the checked reader);
   - :func:`~clutch_ros.bag.reader.read_rig_states` (numpy columns, every field) and with
     the replay's fields only (:data:`~clutch_ros.bag.rig_states.REPLAY_FIELDS`);
   - offline replay, as ``clutch replay`` runs it (:func:`clutch_ros.offline.replay.replay_bag`
     with the replay's fields): ``read_rig_states`` + :func:`clutch_ros.model.estimate_batch`
     with the ``flexiforce_8`` preset (``--law`` overrides its spline law), split into its
     read and estimate parts.
3. Prints samples/s for each, the ratio to real time and to the bare rosbags read, checks
   the replay targets (>= 100x real time, >= 40 % of the bare read), and deletes the bag
   (``--keep DIR`` keeps it there; ``--bag BAG`` measures an existing bag instead).
   ``--no-replay`` skips the replay.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from clutch_ros import interfaces
from clutch_ros.bag.columns import ColumnDecoder
from clutch_ros.bag.reader import BagReader
from clutch_ros.bag.rig_states import REPLAY_FIELDS, read_rig_states
from clutch_ros.bag.typestore import RIG_STATE_TYPE, clutch_typestore, rig_state_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.offline.replay import replay_bag

__all__ = ["BenchResult", "generate_bag", "main", "run"]

START_NS = 1_700_000_000 * 1_000_000_000  # an arbitrary recent epoch [ns]
_BLOCK = 100_000


@dataclass
class BenchResult:
    """Benchmark figures; rates in samples (messages) per second."""

    samples: int
    seconds_of_data: float
    storage: str
    bag_bytes: int
    generate_s: float
    bare_rosbags_per_s: float
    bag_reader_per_s: float
    read_rig_states_per_s: float
    read_replay_fields_per_s: float | None = None
    replay_per_s: float | None = None
    replay_read_s: float | None = None
    replay_estimate_s: float | None = None
    replay_preset: str | None = None

    @property
    def replay_realtime(self) -> float | None:
        """Offline replay speed as a multiple of real time."""
        if self.replay_per_s is None:
            return None
        return self.replay_per_s / (self.samples / self.seconds_of_data)

    @property
    def replay_vs_bare(self) -> float | None:
        """Offline replay throughput as a fraction of the bare rosbags read+deserialize."""
        if self.replay_per_s is None:
            return None
        return self.replay_per_s / self.bare_rosbags_per_s


#: Offline replay targets of issue 6: x real time, fraction of the bare rosbags read.
TARGET_REALTIME = 100.0
TARGET_VS_BARE = 0.40


def _signals(t: np.ndarray) -> dict[str, np.ndarray]:
    """Synthetic rig signals at times ``t`` [s]: a pressure sweep at three slip speeds."""
    rng = np.random.default_rng(int(t[0] * 1000) if len(t) else 0)
    sweep = 20e5 * (1.0 - np.cos(2 * math.pi * t / 20.0))  # 0..40 bar [Pa]
    pressure = np.maximum(sweep + rng.normal(0, 2e3, len(t)), 0.0)
    slip = (10.0, 30.0, 50.0)
    slip_rpm = np.choose((t // 120).astype(int) % 3, slip)
    temp = 35.0 + 115.0 * (1.0 - np.exp(-t / 1800.0))  # degC
    torque = 0.11 * pressure * 3.75e-3 * 16 * 0.06  # mu * F * surfaces * R_eff [N m]
    return {
        "actuating_pressure": pressure,
        "lamella_temperature": temp,
        "oil_temperature": temp - 20.0,
        "input_speed": slip_rpm * 2 * math.pi / 60.0,
        "output_speed": np.zeros(len(t)),
        "slip_speed": slip_rpm * 2 * math.pi / 60.0,
        "measured_torque": torque + rng.normal(0, 2.0, len(t)),
        "torque_request": torque,
        "pump_current": 2.0 + pressure / 1e6,
    }


def generate_bag(
    path: str | Path, seconds: float, rate_hz: float = 1000.0, storage: str = "mcap"
) -> int:
    """Write a synthetic RigState bag of ``seconds`` [s] at ``rate_hz`` [Hz] to ``path``.

    Returns:
        the number of messages written.

    """
    store = clutch_typestore()
    template = rig_state_msg(
        START_NS,
        frame_id="rig",
        ff_voltages=np.zeros(8),
        wheel_speeds=np.zeros(4),
        has_measured_torque=True,
    )
    raw = np.frombuffer(bytes(store.serialize_cdr(template, RIG_STATE_TYPE)), dtype=np.uint8)
    offsets = ColumnDecoder(store, RIG_STATE_TYPE).offsets(raw.tobytes())
    size = len(raw)
    total = int(round(seconds * rate_hz))
    period_ns = 1e9 / rate_hz
    with BagWriter(path, storage=storage, delete_on_error=True) as writer:
        topic = writer.add_topic(interfaces.RIG_STATE.absolute)
        for first in range(0, total, _BLOCK):
            n = min(_BLOCK, total - first)
            idx = np.arange(first, first + n)
            stamps = START_NS + np.round(idx * period_ns).astype(np.int64)
            block = np.tile(raw, (n, 1))
            columns = {
                "header.stamp.sec": (stamps // 1_000_000_000, "<i4"),
                "header.stamp.nanosec": (stamps % 1_000_000_000, "<u4"),
                "ff_voltages": (np.tile(np.linspace(0.5, 2.0, 8), (n, 1)), "<f8"),
                "wheel_speeds": (np.zeros((n, 4)), "<f8"),
            }
            for name, values in _signals((stamps - START_NS) / 1e9).items():
                columns[name] = (values, "<f8")
            for name, (values, dtype) in columns.items():
                arr = np.ascontiguousarray(values, dtype=dtype).reshape(n, -1)
                off = offsets[name]
                block[:, off : off + arr.shape[1] * arr.itemsize] = arr.view(np.uint8)
            data = memoryview(block.tobytes())
            write = writer.write_raw
            for i in range(n):
                write(topic, int(stamps[i]), data[i * size : (i + 1) * size])
    return total


def _rate(count: int, seconds: float) -> float:
    return count / seconds if seconds > 0 else float("inf")


def run(
    seconds: float = 3600.0,
    rate_hz: float = 1000.0,
    storage: str = "mcap",
    keep: str | Path | None = None,
    replay: bool = True,
    preset: str = "flexiforce_8",
    bag: str | Path | None = None,
    law: str | None = None,
) -> BenchResult:
    """Generate the bag, measure the read paths and the replay, delete it (unless ``keep``).

    With ``bag``, measure that existing bag instead (``seconds`` is then taken from its
    sample count and ``rate_hz``).
    """
    with tempfile.TemporaryDirectory(prefix="clutch-bench-") as tmp:
        gen = 0.0
        if bag is not None:
            path = Path(bag)
            n = len(read_rig_states(path, fields=REPLAY_FIELDS))
            seconds = n / rate_hz
            storage = "sqlite3" if any(path.glob("*.db3")) else "mcap"
        else:
            path = (Path(keep) if keep else Path(tmp)) / f"bench_{int(seconds)}s_{storage}"
            t0 = time.perf_counter()
            n = generate_bag(path, seconds, rate_hz, storage)
            gen = time.perf_counter() - t0
        nbytes = sum(f.stat().st_size for f in path.iterdir()) if path.is_dir() else 0
        store = clutch_typestore()

        t0 = time.perf_counter()
        count = 0
        with Reader(path) as reader:
            for conn, _, data in reader.messages():
                store.deserialize_cdr(data, conn.msgtype)
                count += 1
        bare = _rate(count, time.perf_counter() - t0)
        if count != n:
            raise RuntimeError(f"bare rosbags read {count} of {n} messages")

        t0 = time.perf_counter()
        with BagReader(path, store=store) as bag:
            count = sum(1 for _ in bag.messages())
        checked = _rate(count, time.perf_counter() - t0)

        t0 = time.perf_counter()
        arrays = read_rig_states(path, store=store)
        fast = _rate(len(arrays), time.perf_counter() - t0)
        del arrays
        t0 = time.perf_counter()
        arrays = read_rig_states(path, store=store, fields=REPLAY_FIELDS)
        fields = _rate(len(arrays), time.perf_counter() - t0)
        del arrays
        res = BenchResult(n, n / rate_hz, storage, nbytes, gen, bare, checked, fast, fields)
        if replay:
            params = load_params(preset_path(preset))
            if law:
                params = params.with_law(law)
            t0 = time.perf_counter()
            result = replay_bag(path, params, store=store, fields=REPLAY_FIELDS)
            total = time.perf_counter() - t0
            if result.summary["accepted"] != n:
                raise RuntimeError(f"replay accepted {result.summary['accepted']} of {n}")
            res.replay_per_s = _rate(n, total)
            res.replay_read_s = result.summary["read_s"]
            res.replay_estimate_s = result.summary["estimate_s"]
            res.replay_preset = preset if not law else f"{preset}, {law}"
            del result
    return res


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark from the command line and print samples/s."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.bag_replay",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--seconds", type=float, default=3600.0, help="bag length [s]")
    parser.add_argument("--rate", type=float, default=1000.0, help="sample rate [Hz]")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--keep", metavar="DIR", help="write the bag into DIR and keep it")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--no-replay", action="store_true", help="measure the reads only")
    parser.add_argument("--preset", default="flexiforce_8", help="estimator preset of the replay")
    parser.add_argument("--law", help="spline law of the replay (default: the preset's)")
    parser.add_argument("--bag", help="measure this existing bag (no generation)")
    args = parser.parse_args(argv)
    res = run(args.seconds, args.rate, args.storage, args.keep, not args.no_replay, args.preset,
              args.bag, args.law)
    if args.json:
        doc = asdict(res)
        doc.update(replay_realtime=res.replay_realtime, replay_vs_bare=res.replay_vs_bare)
        print(json.dumps(doc))
        return 0
    print(
        f"bag: {res.samples} RigState messages ({res.seconds_of_data:g} s at {args.rate:g} Hz),"
        f" {res.storage}, {res.bag_bytes / 1e6:.1f} MB, generated in {res.generate_s:.1f} s"
    )
    for label, rate in (
        ("bare rosbags read+deserialize", res.bare_rosbags_per_s),
        ("BagReader.messages (checked)", res.bag_reader_per_s),
        ("read_rig_states (numpy)", res.read_rig_states_per_s),
        ("read_rig_states (replay fields)", res.read_replay_fields_per_s),
    ):
        print(
            f"{label:31s} {rate:12,.0f} samples/s  {rate / args.rate:8,.0f}x real time  "
            f"{rate / res.bare_rosbags_per_s:5.2f}x bare"
        )
    if res.replay_per_s is None:
        return 0
    label = f"offline replay ({res.replay_preset})"
    rate = res.replay_per_s
    print(
        f"{label:31s} {rate:12,.0f} samples/s  {res.replay_realtime:8,.0f}x real time  "
        f"{res.replay_vs_bare:5.2f}x bare"
    )
    read_s, est_s = res.replay_read_s or 0.0, res.replay_estimate_s or 0.0
    whole = max(read_s + est_s, 1e-12)
    print(
        f"  of which read_rig_states {read_s:.2f} s ({100 * read_s / whole:.0f} %), "
        f"estimate_batch {est_s:.2f} s ({100 * est_s / whole:.0f} %; "
        f"{_rate(res.samples, est_s):,.0f} samples/s)"
    )
    ok_rt = res.replay_realtime >= TARGET_REALTIME
    ok_bare = res.replay_vs_bare >= TARGET_VS_BARE
    print(
        f"replay targets: >= {TARGET_REALTIME:g}x real time {'met' if ok_rt else 'NOT MET'}, "
        f">= {100 * TARGET_VS_BARE:g} % of the bare read {'met' if ok_bare else 'NOT MET'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
