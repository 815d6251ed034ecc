"""``clutch import FILE... -o BAG``: rig CSV or Vector ASC/BLF CAN logs -> RigState bags.

CSV: the README.md columns (units in the header names, converted to SI), one message per row.
CAN logs (any python-can log format, picked by suffix: .asc, .blf, .log, .trc, .csv of
python-can ...): decoded through ``params/rig.dbc`` by the same path as the live bridge, one
RigState per ``--period`` of log time in which a frame arrived (a sample repeating the last
stamp carries nothing new and is left out); ``--frames`` also stores every frame as it was
logged (error frames included) as ``CanFrame`` on ``/can_frames`` (CAN FD payloads beyond 8
bytes are cut to 8, ``dlc`` keeps the length, as the live bridge does). With several
inputs, ``-o`` is a directory and each input becomes ``<o>/<input stem>``. A progress bar
goes to stderr when it is a terminal; an import that fails deletes its partial bag.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from clutch_ros import interfaces
from clutch_ros.bag.channel_map import load_map
from clutch_ros.bag.csv_import import import_csv
from clutch_ros.bag.mapped_import import MDF_SUFFIXES, import_mapped
from clutch_ros.bag.typestore import CAN_FRAME_TYPE, RIG_STATE_TYPE, can_frame_msg, rig_state_msg
from clutch_ros.bag.writer import BagWriter
from clutch_ros.canbus import LogSource, RigDatabase, RigStateAssembler
from clutch_ros.canbus.logsource import Assembler
from clutch_ros.cli.dispatch import emit_json
from clutch_ros.errors import ClutchError
from clutch_ros.rigstate import msg_fields

__all__ = ["add_parser", "run"]

CSV_SUFFIXES = {".csv", ".txt"}


def add_parser(sub) -> None:
    """Register ``clutch import``."""
    p = sub.add_parser("import", help="import rig CSV or CAN logs (ASC/BLF) into bags",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+", metavar="FILE", help="rig CSV or CAN log files")
    p.add_argument("-o", "--output", required=True, metavar="BAG",
                   help="bag to create (a directory of bags for several inputs)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="storage plugin of the bags written (default: mcap)")
    p.add_argument("--format", choices=("auto", "csv", "can"), default="auto",
                   help="input format (default: by suffix; python-can's own CSV needs can)")
    p.add_argument("--period", type=float, default=0.001,
                   help="CAN logs: RigState sample period of log time [s] (default 0.001)")
    p.add_argument("--dbc", help="CAN logs: DBC file (default: the package's rig.dbc)")
    p.add_argument("--frames", action="store_true",
                   help="CAN logs: also store every frame as CanFrame on /can_frames")
    p.add_argument("--map", metavar="MAP.yaml", help="channel map: which MDF4 channel or CSV "
                   "column feeds each RigState field, with units (required for .mf4 files; "
                   "see clutch_ros/bag/channel_map.py)")
    p.add_argument("--json", action="store_true", help="print a JSON list of imports")
    p.set_defaults(func=run)


class _Progress:
    """A one-line progress bar on stderr (redrawn at most 10 times a second).

    Drawn only when stderr is a terminal (``enabled``), so logs and the one-line error
    messages of a failed import stay clean; :meth:`end` finishes a started line.
    """

    def __init__(self, label: str, enabled: bool | None = None):
        self.label = label
        self._last = 0.0
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._open = False

    def end(self) -> None:
        """Terminate a partly drawn bar (before an error message is printed)."""
        if self._open:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self._open = False

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.1 and fraction < 1.0:
            return
        self._last = now
        filled = int(30 * min(max(fraction, 0.0), 1.0))
        sys.stderr.write(f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] "
                         f"{100 * fraction:5.1f} %")
        self._open = True
        if fraction >= 1.0:
            sys.stderr.write("\n")
            self._open = False
        sys.stderr.flush()


def run(args) -> int:
    """Import every file; print one line (or JSON object) per import."""
    files = [Path(f) for f in args.files]
    for path in files:
        if not path.is_file():
            raise ClutchError(f"{path}: no such file")
    out = Path(args.output)
    if not args.period > 0.0:
        raise ClutchError(f"--period must be > 0 s, got {args.period}")
    targets = [out] if len(files) == 1 else [out / p.stem for p in files]
    if len(files) > 1:
        out.mkdir(parents=True, exist_ok=True)
    results = []
    for path, target in zip(files, targets):
        kind = args.format if args.format != "auto" else (
            "csv" if path.suffix.lower() in CSV_SUFFIXES else "can")
        progress = _Progress(path.name)
        try:
            if args.map or path.suffix.lower() in MDF_SUFFIXES:
                if not args.map:
                    raise ClutchError(f"{path}: an MDF file needs --map MAP.yaml (which "
                                      "channel feeds which RigState field)")
                n, span = import_mapped(path, target, load_map(args.map), storage=args.storage)
                results.append({"source": str(path), "bag": str(target), "format": "mapped",
                                "messages": n, "duration_s": span, "ignored_columns": []})
            elif kind == "csv":
                s = import_csv(path, target, storage=args.storage, progress=progress)
                results.append({"source": str(path), "bag": str(target), "format": "csv",
                                "messages": s.messages, "duration_s": s.duration_s,
                                "ignored_columns": s.ignored_columns})
            else:
                results.append(_import_can(path, target, args, progress))
            progress(1.0)
        finally:
            progress.end()
        if results[-1]["messages"] == 0:
            sys.stderr.write(f"clutch import: warning: {path}: no RigState sample (no rig "
                             "frame of the DBC in the log); the bag holds none\n")
    if args.json:

        emit_json(results)
    else:
        for r in results:
            sys.stdout.write(f"{r['source']} -> {r['bag']}: {r['messages']} RigState messages "
                             f"({r['format']}, {r['duration_s']:.3f} s)\n")
    return 0


class _Tap:
    """An assembler stand-in that hands every frame to ``sink`` before assembling it."""

    def __init__(self, assembler, sink):
        self._assembler = assembler
        self._sink = sink

    def feed(self, msg) -> None:
        self._sink(msg)
        self._assembler.feed(msg)

    def snapshot(self, now=None):
        return self._assembler.snapshot(now)


def _import_can(path: Path, target: Path, args, progress) -> dict:


    source = LogSource(path)
    source.check()
    assembler = RigStateAssembler(RigDatabase(args.dbc) if args.dbc else RigDatabase())
    size = max(path.stat().st_size, 1)
    counts = {"repeated": 0, "truncated": 0}
    writer = BagWriter(target, storage=args.storage, delete_on_error=True,
                       custom_data={"source": str(path)})
    with writer:
        rig_topic = writer.add_topic(interfaces.RIG_STATE.absolute, RIG_STATE_TYPE)
        frame_topic = (writer.add_topic(interfaces.CAN_FRAMES.absolute, CAN_FRAME_TYPE)
                       if args.frames else None)

        def store_frame(msg) -> None:
            assert frame_topic is not None  # tapped only with --frames
            stamp_ns = _stamp_ns(path, msg.timestamp)
            data = bytes(msg.data)
            counts["truncated"] += len(data) > 8
            writer.write(frame_topic, stamp_ns, can_frame_msg(
                stamp_ns, msg.arbitration_id, data[:8], dlc=min(msg.dlc, 255),
                is_rtr=msg.is_remote_frame, is_extended=msg.is_extended_id,
                is_error=msg.is_error_frame))

        feeder: Assembler = _Tap(assembler, store_frame) if frame_topic else assembler
        last_ns = None
        for n, sample in enumerate(source.samples(feeder, args.period)):
            if n % 2000 == 0:
                progress(min(0.99, source.frames_read * 40 / size))
            if sample.stamp is None:
                continue
            stamp_ns = _stamp_ns(path, sample.stamp)
            if stamp_ns == last_ns:  # no frame since the last sample: nothing new
                counts["repeated"] += 1
                continue
            last_ns = stamp_ns
            writer.write(rig_topic, stamp_ns,
                         rig_state_msg(stamp_ns, frame_id="rig", **msg_fields(sample)))
    rig_count = writer.written[rig_topic]
    counters = assembler.counters()
    first, last = (writer.first_ns or 0), (writer.last_ns or 0)
    result = {"source": str(path), "bag": str(target), "format": "can",
              "messages": rig_count, "duration_s": (last - first) / 1e9 if rig_count else 0.0,
              "frames": counters.frames_total, "decoded_frames": counters.decoded_frames,
              "unknown_frames": counters.unknown_frames, "error_frames": counters.error_frames,
              "decode_errors": counters.decode_errors, "repeated_samples": counts["repeated"]}
    if frame_topic:
        result.update(can_frames=writer.written[frame_topic],
                      truncated_fd_frames=counts["truncated"])
    return result


def _stamp_ns(path: Path, seconds: float) -> int:
    """Log time [s] -> ROS stamp [ns]; a clear error outside ROS Time's int32 seconds."""
    stamp_ns = int(round(seconds * 1e9))
    if not 0 <= stamp_ns < 2**31 * 1_000_000_000:
        raise ClutchError(f"{path}: frame time {seconds:.6f} s does not fit a ROS Time "
                          "(0 .. 2^31 s since the epoch)")
    return stamp_ns
