"""Write benchmark of the recorder's bag path: crash-safe chunks against rosbags' own.

``python -m benchmarks.bag_write [--messages 200000] [--rate 200] [--json]``

Writes ``--messages`` RigState messages (raw CDR, one per ``write_raw`` call, as the
recorder does) into MCAP bags, timing wall and CPU time (``time.process_time``) per case:

- ``rosbags``: the baseline, rosbags' own ``Writer`` (chunks of 1 MiB of records, no CRC,
  buffered writes), which :class:`~clutch_ros.bag.writer.BagWriter` used before;
- ``bagwriter``: :class:`BagWriter` without ``chunk_interval`` (1 MiB chunks with a CRC);
- ``recorder``: as the recorder writes, ``chunk_interval`` 1 s and fsync per chunk; the
  messages are written as fast as possible, so few chunks close on time;
- ``per_chunk``: the cost of one time-closed chunk (CRC, message index, flush, fsync) at
  ``--rate`` Hz: ``chunk_interval`` 1/``--chunks-per-s`` s, messages paced so each chunk holds
  ``--rate``/``--chunks-per-s`` messages; CPU per closed chunk, from the CPU time of the whole
  run minus the CPU time of the same messages in the ``bagwriter`` case.

It prints messages/s and µs of CPU per message for each case, the CPU share a 200 Hz
(``--rate``) recording spends writing, and deletes the bags.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from clutch_ros.bag.arrays import TemplateSerializer
from clutch_ros.bag.typestore import RIG_STATE_TYPE, clutch_typestore
from clutch_ros.bag.writer import BagWriter

__all__ = ["main", "run"]

T0 = 1_700_000_000 * 10**9  # [ns]


def _payloads(n: int) -> list[bytes]:
    ser = TemplateSerializer(RIG_STATE_TYPE, frame_id="rig", ff_voltages=np.zeros(8))
    stamps = T0 + np.arange(n, dtype=np.int64) * 5_000_000
    block = ser.serialize_stamped(stamps, {"measured_torque": np.arange(n, dtype=float)})
    return [row.tobytes() for row in block]


def _time(write, payloads, pace: float = 0.0) -> tuple[float, float]:
    """(wall s, CPU s) of ``write(i, data)`` over the payloads, ``pace`` s apart if > 0."""
    wall, cpu = time.perf_counter(), time.process_time()
    start = time.monotonic()
    for i, data in enumerate(payloads):
        if pace:
            delay = start + i * pace - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        write(i, data)
    return time.perf_counter() - wall, time.process_time() - cpu


def _rosbags(path: Path, payloads) -> tuple[float, float]:
    writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    conn = writer.add_connection("/rig_state", RIG_STATE_TYPE, typestore=clutch_typestore())
    wall, cpu = _time(lambda i, d: writer.write(conn, T0 + i * 5_000_000, d), payloads)
    writer.close()
    return wall, cpu


def _bagwriter(path: Path, payloads, pace: float = 0.0, **kwargs) -> tuple[float, float, int]:
    writer = BagWriter(path, verify=False, **kwargs).open()
    name = writer.add_topic("/rig_state", RIG_STATE_TYPE)
    wall, cpu = _time(lambda i, d: writer.write_raw(name, T0 + i * 5_000_000, d), payloads,
                      pace)
    chunks = writer._writer.storage.chunks_closed  # still open: the storage writer is there
    writer.close()
    return wall, cpu, chunks


def run(messages: int, rate: float, chunks_per_s: float, paced: int) -> dict:
    """Measure every case; return the figures (module doc)."""
    payloads = _payloads(messages)
    out: dict = {"messages": messages, "bytes_per_message": len(payloads[0])}
    with tempfile.TemporaryDirectory(prefix="bag-write-") as tmp:
        root = Path(tmp)
        cases = {
            "rosbags": _rosbags(root / "a", payloads),
            "bagwriter": _bagwriter(root / "b", payloads)[:2],
            "recorder": _bagwriter(root / "c", payloads, chunk_interval=1.0, sync=True)[:2],
        }
        for case, (wall, cpu) in cases.items():
            out[case] = {"per_s": messages / wall, "cpu_us_per_msg": 1e6 * cpu / messages}
        few = payloads[:paced]
        _, base_cpu, _ = _bagwriter(root / "d", few, pace=1.0 / rate)
        wall, cpu, chunks = _bagwriter(root / "e", few, pace=1.0 / rate,
                                       chunk_interval=1.0 / chunks_per_s, sync=True)
        out["per_chunk"] = {"chunks": chunks, "cpu_ms_per_chunk":
                            1e3 * max(cpu - base_cpu, 0.0) / max(chunks, 1)}
    per_s = out["recorder"]["cpu_us_per_msg"] * 1e-6 * rate + \
        out["per_chunk"]["cpu_ms_per_chunk"] * 1e-3
    out["recorder_cpu_share_at_rate"] = {"rate_hz": rate, "share": per_s}
    return out


def main(argv=None) -> int:
    """Run the benchmark from the command line (module doc)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--messages", type=int, default=200_000)
    parser.add_argument("--rate", type=float, default=200.0, help="[Hz] paced case")
    parser.add_argument("--chunks-per-s", type=float, default=20.0,
                        help="[1/s] chunk closes in the paced case (1 in the recorder)")
    parser.add_argument("--paced", type=int, default=600, help="messages of the paced case")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    res = run(args.messages, args.rate, args.chunks_per_s, args.paced)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{res['messages']} RigState messages of {res['bytes_per_message']} B")
    for case in ("rosbags", "bagwriter", "recorder"):
        r = res[case]
        print(f"  {case:10s} {r['per_s']:12,.0f} msg/s  {r['cpu_us_per_msg']:6.2f} µs CPU/msg")
    c = res["per_chunk"]
    print(f"  one time-closed chunk (CRC, index, flush, fsync): {c['cpu_ms_per_chunk']:.3f} ms "
          f"CPU ({c['chunks']} chunks)")
    s = res["recorder_cpu_share_at_rate"]
    print(f"  recorder writing at {s['rate_hz']:.0f} Hz, 1 chunk/s: {100 * s['share']:.3f} % "
          "of a core")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
