"""Import a rig CSV export into a RigState bag (the ``clutch import FILE.csv`` back end).

Contract (README.md, "The clutch command"): the header names carry units; ``time_s``,
``pressure_bar``, ``lamella_temp_c`` and ``diff_speed_rpm`` are required; ``oil_temp_c``,
``input_speed_rpm``, ``output_speed_rpm``, ``torque_nm``, ``torque_request_nm``,
``ff_front_1_v`` ... ``ff_front_4_v``, ``ff_rear_1_v`` ... ``ff_rear_4_v``, ``wheel_fl_rpm``,
``wheel_fr_rpm``, ``wheel_rl_rpm``,
``wheel_rr_rpm`` and ``pump_current_a`` are optional. One ``RigState`` per data row on
``/rig_state`` (absolute, as ``ros2 bag record`` stores it), bag timestamp = header stamp =
``time_offset_ns`` + time.

Units are converted to SI (bar -> Pa, rpm -> rad/s); the unit suffix may also be any other
listed in :data:`UNITS` (``pressure_kpa``, ``diff_speed_rad_s``, ``time_ms``, ``oil_temp_k``...).
Header names are case-insensitive; unknown columns are ignored (listed in the summary).

- ``diff_speed`` -> ``slip_speed`` (as measured; not recomputed from input/output).
- ``torque`` -> ``measured_torque`` with ``has_measured_torque``; an empty cell means no
  measurement (NaN, flag false).
- Empty optional cells and absent optional columns give NaN (never a fake 0 degC or 0 rad/s);
  required cells must be finite numbers.
- ``ff_voltages`` holds the FlexiForce columns present, front 1-4 then rear 1-4 (the layout
  is stored in the bag's ``custom_data`` as ``clutch_ros.ff_voltages``); ``wheel_speeds`` is
  FL, FR, RL, RR when any wheel column is present (NaN for a missing wheel), else empty.
- Time must strictly increase. Delimiter ``,``, ``;`` or tab (detected from the header); with
  ``;`` or tab a decimal comma is accepted. Blank lines and lines starting with ``#`` are
  skipped. Errors name the file, the 1-based line number and the column.

The file is streamed row by row (constant memory); ``progress(fraction)`` is called as the file
is read. On any error the partial bag is deleted.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from clutch_ros.bag.errors import BagExistsError, CsvError
from clutch_ros.bag.typestore import topic_name
from clutch_ros.bag.writer import write_rig_states
from clutch_ros.interfaces import NS_PER_S, RIG_STATE, SI_UNITS, ns_to_s, unit_table
from clutch_ros.rigstate import CSV_UNITS, FIELDS

__all__ = ["REQUIRED", "UNITS", "ImportSummary", "import_csv"]

#: Accepted unit suffixes per quantity: (scale, offset) so that SI = value * scale + offset
#: (time to ns): the unit table :data:`clutch_ros.interfaces.UNITS` in its CSV spelling
#: (:func:`~clutch_ros.interfaces.fold_unit`: ``pressure_kpa``, ``diff_speed_rad_s``).
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    quantity: {spelling: (u.scale * (NS_PER_S if quantity == "time" else 1.0), u.offset)
               for spelling, u in unit_table(quantity, fold=True).items()}
    for quantity in SI_UNITS if quantity
}

# column stem -> (RigState field or "time", quantity, canonical contract name), from the one
# RigState field table (clutch_ros.rigstate)
_STEMS: dict[str, tuple[str, str, str]] = {
    "time": ("time", "time", "time_s"),
    **{stem: (spec.name, spec.quantity, f"{stem}_{CSV_UNITS[spec.quantity]}")
       for spec in FIELDS for stem in spec.csv_stems},
}
#: Required columns (canonical names; other units of the same quantity are accepted).
REQUIRED = ("time_s", "pressure_bar", "lamella_temp_c", "diff_speed_rpm")
_REQUIRED_STEMS = ("time", "pressure", "lamella_temp", "diff_speed")
_OPTIONAL_SCALARS = ("oil_temp", "input_speed", "output_speed", "torque_request", "pump_current")
_WHEELS = ("wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr")
_FF = tuple(f"ff_{side}_{i}" for side in ("front", "rear") for i in range(1, 5))


@dataclass
class ImportSummary:
    """Result of an import.

    Attributes:
        source: the CSV file.
        bag: the bag written.
        storage: ``mcap`` or ``sqlite3``.
        topic: topic written (absolute).
        messages: RigState messages written (= data rows) [messages].
        start_ns: first stamp [ns since epoch].
        end_ns: last stamp [ns since epoch].
        columns: CSV column -> RigState field it filled.
        ignored_columns: CSV columns not recognised.
        ff_layout: CSV columns forming ``ff_voltages``, in order.
        seconds: wall time of the import [s].

    """

    source: Path
    bag: Path
    storage: str
    topic: str
    messages: int
    start_ns: int
    end_ns: int
    columns: dict[str, str] = field(default_factory=dict)
    ignored_columns: list[str] = field(default_factory=list)
    ff_layout: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def duration_s(self) -> float:
        """Time covered by the import [s]."""
        return ns_to_s(self.end_ns - self.start_ns)


def _match(name: str) -> tuple[str, tuple[float, float]] | None:
    """``(stem, (scale, offset))`` of a header name, longest stem first; None if unknown."""
    best = None
    for stem, (_, quantity, _) in _STEMS.items():
        unit = name[len(stem) + 1 :] if name.startswith(stem + "_") else None
        if unit in UNITS[quantity] and (best is None or len(stem) > len(best[0])):
            best = (stem, UNITS[quantity][unit])
    return best


class _Source:
    """Physical lines of a CSV file as text, counting the bytes consumed (for progress)."""

    def __init__(self, fh: BinaryIO):
        self.fh = fh
        self.bytes_read = 0

    def __iter__(self) -> Iterator[str]:
        first = True
        for raw in self.fh:
            self.bytes_read += len(raw)
            text = raw.decode("utf-8", errors="replace")
            if first:
                text = text.removeprefix("\ufeff")
                first = False
            yield text


def _header(lines: Iterator[str], path: Path) -> tuple[int, str]:
    """``(line number, text)`` of the header: the first line not blank and not ``#``."""
    for number, text in enumerate(lines, start=1):
        if text.strip() and not text.lstrip().startswith("#"):
            return number, text
    raise CsvError(path, "empty file: no header line")


def _sniff(header: str) -> str:
    """Guess the delimiter of a header line: the most frequent of ``,``, ``;`` and tab."""
    counts = {d: header.count(d) for d in (",", ";", "\t")}
    best = max(counts, key=lambda d: counts[d])
    return best if counts[best] else ","


class _Parser:
    """Column plan for one CSV header; turns rows into ``(stamp_ns, fields)``."""

    def __init__(self, path: Path, names: list[str], line: int, time_offset_ns: int):
        self.path = path
        self.names = names
        self.offset = time_offset_ns
        self.by_stem: dict[str, tuple[int, float, float]] = {}
        self.columns: dict[str, str] = {}
        self.ignored: list[str] = []
        for idx, name in enumerate(names):
            key = name.strip().lower()
            hit = _match(key)
            if hit is None:
                if key:
                    self.ignored.append(name.strip())
                continue
            stem, (scale, off) = hit
            if stem in self.by_stem:
                other = names[self.by_stem[stem][0]].strip()
                raise CsvError(
                    path,
                    f"columns {other!r} and {name.strip()!r} give the same quantity",
                    line=line,
                    column=name.strip(),
                )
            self.by_stem[stem] = (idx, scale, off)
            self.columns[name.strip()] = _STEMS[stem][0]
        for stem in _REQUIRED_STEMS:
            if stem not in self.by_stem:
                found = ", ".join(n.strip() for n in names) or "none"
                raise CsvError(
                    path,
                    f"missing required column {_STEMS[stem][2]!r} (columns: {found})",
                    line=line,
                    column=_STEMS[stem][2],
                )
        self.ff = [s for s in _FF if s in self.by_stem]
        self.ff_layout = [names[self.by_stem[s][0]].strip() for s in self.ff]
        self.wheels = any(w in self.by_stem for w in _WHEELS)
        self.prev_ns: int | None = None

    def _value(self, row: list[str], stem: str, line: int, required: bool, comma: bool) -> float:
        spec = self.by_stem.get(stem)
        if spec is None:
            return math.nan
        idx, scale, off = spec
        text = row[idx].strip() if idx < len(row) else ""
        column = self.names[idx].strip()
        if not text:
            if required:
                raise CsvError(self.path, "empty value", line=line, column=column)
            return math.nan
        try:
            value = float(text.replace(",", ".") if comma else text)
        except ValueError:
            raise CsvError(
                self.path,
                f"cannot parse {text!r} as a number in column {column!r}",
                line=line,
                column=column,
            ) from None
        if required and not math.isfinite(value):
            raise CsvError(
                self.path,
                f"{text!r} is not a finite number in column {column!r}",
                line=line,
                column=column,
            )
        return value * scale + off

    def row(self, row: list[str], line: int, comma: bool) -> tuple[int, dict[str, Any]]:
        extra = [v for v in row[len(self.names) :] if v.strip()]
        if len(row) < len(self.names) or extra:
            raise CsvError(
                self.path, f"expected {len(self.names)} values, found {len(row)}", line=line
            )
        stamp_ns = round(self._value(row, "time", line, True, comma)) + self.offset
        column = self.names[self.by_stem["time"][0]].strip()
        if stamp_ns < 0:
            raise CsvError(
                self.path,
                f"time {ns_to_s(stamp_ns - self.offset):.9g} s gives a stamp before 1970; "
                "import with a time offset",
                line=line,
                column=column,
            )
        if self.prev_ns is not None and stamp_ns <= self.prev_ns:
            raise CsvError(
                self.path,
                f"time does not increase ({ns_to_s(stamp_ns - self.offset):.9g} s after "
                f"{ns_to_s(self.prev_ns - self.offset):.9g} s)",
                line=line,
                column=column,
            )
        self.prev_ns = stamp_ns
        fields: dict[str, Any] = {
            "actuating_pressure": self._value(row, "pressure", line, True, comma),
            "lamella_temperature": self._value(row, "lamella_temp", line, True, comma),
            "slip_speed": self._value(row, "diff_speed", line, True, comma),
        }
        for stem in _OPTIONAL_SCALARS:
            fields[_STEMS[stem][0]] = self._value(row, stem, line, False, comma)
        torque = self._value(row, "torque", line, False, comma)
        fields["measured_torque"] = torque
        fields["has_measured_torque"] = not math.isnan(torque)
        if self.ff:
            fields["ff_voltages"] = [self._value(row, s, line, False, comma) for s in self.ff]
        if self.wheels:
            fields["wheel_speeds"] = [self._value(row, w, line, False, comma) for w in _WHEELS]
        return stamp_ns, fields


def import_csv(
    path: str | Path,
    out_bag: str | Path,
    storage: str = "mcap",
    progress: Callable[[float], None] | None = None,
    *,
    topic: str = RIG_STATE.absolute,
    frame_id: str = "rig",
    time_offset_ns: int = 0,
) -> ImportSummary:
    """Import the rig CSV ``path`` into a new bag ``out_bag`` of RigState messages.

    Args:
        path: CSV file (see module docstring for the columns).
        out_bag: bag directory to create (must not exist).
        storage: ``"mcap"`` (default) or ``"sqlite3"``.
        progress: called with the fraction of the file read (0..1), at most ~100 times.
        topic: topic to write (stored absolute).
        frame_id: header frame id.
        time_offset_ns: added to the CSV time to form stamps [ns since epoch].

    Raises:
        CsvError: file missing/empty, missing required column, bad or non-increasing value
            (with the line number and column).
        BagExistsError: ``out_bag`` exists.

    """
    t0 = time.perf_counter()
    src, out = Path(path), Path(out_bag)
    if out.exists():
        raise BagExistsError(out, "output exists already; bags are never overwritten")
    try:
        fh = src.open("rb")
    except OSError as err:
        raise CsvError(src, f"cannot open: {err.strerror or err}") from err
    with fh:
        size = max(src.stat().st_size, 1)
        source = _Source(fh)
        lines = iter(source)
        header_line, header_text = _header(lines, src)
        delim = _sniff(header_text)
        names = next(csv.reader([header_text], delimiter=delim))
        parser = _Parser(src, names, header_line, int(time_offset_ns))
        reader = csv.reader(lines, delimiter=delim, strict=True)
        comma = delim != ","
        step = size / 100.0
        next_report = step
        count = 0

        def samples() -> Iterator[tuple[int, dict[str, Any]]]:
            nonlocal next_report, count
            try:
                for row in reader:
                    if not any(v.strip() for v in row) or row[0].lstrip().startswith("#"):
                        continue
                    yield parser.row(row, header_line + reader.line_num, comma)
                    count += 1
                    if progress is not None and source.bytes_read >= next_report:
                        progress(min(source.bytes_read / size, 1.0))
                        next_report = source.bytes_read + step
            except csv.Error as err:
                raise CsvError(
                    src, f"malformed CSV: {err}", line=header_line + reader.line_num
                ) from err
            if count == 0:
                raise CsvError(src, "no data rows after the header", line=header_line)

        custom = {
            "clutch_ros.importer": "csv",
            "clutch_ros.source": src.name,
            "clutch_ros.ff_voltages": ",".join(parser.ff_layout),
        }
        writer = write_rig_states(
            out, samples(), storage=storage, topic=topic, frame_id=frame_id, custom_data=custom
        )
    if progress is not None:
        progress(1.0)
    return ImportSummary(
        source=src,
        bag=out,
        storage=writer.storage,
        topic=topic_name(topic),
        messages=count,
        start_ns=writer.first_ns or 0,
        end_ns=writer.last_ns or 0,
        columns=parser.columns,
        ignored_columns=parser.ignored,
        ff_layout=parser.ff_layout,
        seconds=time.perf_counter() - t0,
    )
