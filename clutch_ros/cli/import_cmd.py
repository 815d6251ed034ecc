"""``clutch import FILE... -o BAG``: rig CSV or Vector ASC/BLF CAN logs -> RigState bags.

CSV: the DESIGN.md columns (units in the header names, converted to SI), one message per row.
CAN logs (any python-can log format, picked by suffix: .asc, .blf, .log, .trc, .csv of
python-can ...): decoded through ``params/rig.dbc`` by the same path as the live bridge, one
RigState per ``--period`` of log time. With several inputs, ``-o`` is a directory and each
input becomes ``<o>/<input stem>``. A progress bar goes to stderr.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from clutch_ros.errors import ClutchError

__all__ = ["add_parser", "run"]

CSV_SUFFIXES = {".csv", ".txt"}


def add_parser(sub) -> None:
    """Register ``clutch import``."""
    p = sub.add_parser("import", help="import rig CSV or CAN logs (ASC/BLF) into bags",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+", metavar="FILE", help="rig CSV or CAN log files")
    p.add_argument("-o", "--output", required=True, metavar="BAG",
                   help="bag to create (a directory of bags for several inputs)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--format", choices=("auto", "csv", "can"), default="auto",
                   help="input format (default: by suffix; python-can's own CSV needs can)")
    p.add_argument("--period", type=float, default=0.001,
                   help="CAN logs: RigState sample period of log time [s] (default 0.001)")
    p.add_argument("--dbc", help="CAN logs: DBC file (default: the package's rig.dbc)")
    p.add_argument("--json", action="store_true", help="print a JSON list of imports")
    p.set_defaults(func=run)


class _Progress:
    """A one-line progress bar on stderr (redrawn at most 10 times a second)."""

    def __init__(self, label: str):
        self.label = label
        self._last = 0.0

    def __call__(self, fraction: float) -> None:
        now = time.monotonic()
        if now - self._last < 0.1 and fraction < 1.0:
            return
        self._last = now
        filled = int(30 * min(max(fraction, 0.0), 1.0))
        sys.stderr.write(f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] "
                         f"{100 * fraction:5.1f} %")
        if fraction >= 1.0:
            sys.stderr.write("\n")
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
        if kind == "csv":
            from clutch_ros.bag.csv_import import import_csv

            s = import_csv(path, target, storage=args.storage, progress=progress)
            results.append({"source": str(path), "bag": str(s.bag), "format": "csv",
                            "messages": s.messages, "duration_s": s.duration_s,
                            "ignored_columns": s.ignored_columns})
        else:
            results.append(_import_can(path, target, args, progress))
        progress(1.0)
    if args.json:
        from clutch_ros.cli import emit_json

        emit_json(results)
    else:
        for r in results:
            sys.stdout.write(f"{r['source']} -> {r['bag']}: {r['messages']} RigState messages "
                             f"({r['format']}, {r['duration_s']:.3f} s)\n")
    return 0


def _import_can(path: Path, target: Path, args, progress) -> dict:
    import math

    from clutch_ros.bag.writer import write_rig_states
    from clutch_ros.canbus import LogSource, RigDatabase, RigStateAssembler

    source = LogSource(path)
    source.check()
    assembler = RigStateAssembler(RigDatabase(args.dbc) if args.dbc else RigDatabase())
    size = max(path.stat().st_size, 1)
    fields = ("actuating_pressure", "lamella_temperature", "oil_temperature", "input_speed",
              "output_speed", "slip_speed", "measured_torque", "torque_request", "pump_current")

    def samples():
        for n, sample in enumerate(source.samples(assembler, args.period)):
            if sample.stamp is None:
                continue
            values = {name: float(getattr(sample, name)) for name in fields}
            values.update(has_measured_torque=bool(sample.has_measured_torque and
                                                   math.isfinite(sample.measured_torque)),
                          ff_voltages=list(sample.ff_voltages),
                          wheel_speeds=list(sample.wheel_speeds),
                          stale_mask=int(sample.stale_mask))
            if n % 2000 == 0:
                progress(min(0.99, source.frames_read * 40 / size))
            yield int(round(sample.stamp * 1e9)), values

    writer = write_rig_states(target, samples(), storage=args.storage,
                              custom_data={"source": str(path)})
    counters = assembler.counters()
    first, last = writer.first_ns or 0, writer.last_ns or 0
    return {"source": str(path), "bag": str(target), "format": "can",
            "messages": sum(writer.written.values()), "duration_s": (last - first) / 1e9,
            "frames": counters.frames_total, "decoded_frames": counters.decoded_frames,
            "unknown_frames": counters.unknown_frames, "error_frames": counters.error_frames,
            "decode_errors": counters.decode_errors}
