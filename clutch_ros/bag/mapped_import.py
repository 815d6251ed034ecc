"""Import MDF4 measurements (``.mf4``, CANape / INCA) and foreign CSVs through a channel map.

``clutch import run.mf4 --map map.yaml -o BAG`` reads the map's channels with asammdf
(pinned in requirements.txt), resamples them to one time base (the map's ``time`` channel,
else the time base of ``actuating_pressure``; other channels are interpolated linearly with
asammdf's ``Signal.interp``), converts their units to SI (:mod:`clutch_ros.bag.channel_map`)
and writes one RigState per time-base sample. The same map serves a CSV whose columns have
other names (``clutch import other.csv --map map.yaml``): each map channel is a column
name, the ``time`` entry names the time column. Stamps are the file's relative time plus
``time_offset_ns`` (0: the same stamps as the CSV import of the same data).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from clutch_ros.bag.channel_map import ChannelMap, MapError, samples
from clutch_ros.bag.errors import BagExistsError
from clutch_ros.bag.writer import write_rig_states

__all__ = ["MDF_SUFFIXES", "import_mapped", "read_csv_channels", "read_mdf_channels"]

MDF_SUFFIXES = (".mf4", ".mdf", ".dat")


def read_mdf_channels(path: Path, cmap: ChannelMap) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return (time base [s], {channel: raw values on it}) of the map's channels in an MDF."""
    # Local import: asammdf loads slowly and is needed only for MDF files.
    from asammdf import MDF

    try:
        mdf = MDF(str(path))
    except Exception as err:  # noqa: BLE001 - asammdf raises many kinds on a bad file
        raise MapError(path, f"cannot read as MDF: {err}") from err
    try:
        missing = [c for c in cmap.channels() if c not in mdf.channels_db]
        if missing:
            raise MapError(path, f"channel(s) {', '.join(missing)} named by {cmap.path.name} "
                                 "not in the file")
        base_name = (cmap.time.channels[0] if cmap.time
                     else next(s for s in cmap.fields
                               if s.field == "actuating_pressure").channels[0])
        base = mdf.get(base_name)
        t = np.asarray(base.samples if cmap.time else base.timestamps, dtype=float)
        if cmap.time:
            t = t * cmap.time.scale
        columns = {}
        for src in cmap.fields:
            for name in src.channels:
                sig = mdf.get(name)
                unit = (sig.unit or "").strip()
                if unit and unit != src.unit:
                    raise MapError(path, f"channel {name} is in {unit!r}, the map says "
                                         f"{src.unit!r} for {src.field}")
                if cmap.time is None:
                    sig = sig.interp(base.timestamps)
                columns[name] = np.asarray(sig.samples, dtype=float)
    finally:
        mdf.close()
    return t, columns


def read_csv_channels(path: Path, cmap: ChannelMap) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Return (time [s], {column: values}) of the map's columns in a CSV (, or ; delimited)."""
    if cmap.time is None:
        raise MapError(cmap.path, "a CSV import needs a 'time' entry naming the time column")
    try:
        text = path.read_text(errors="replace")
    except OSError as err:
        raise MapError(path, f"cannot open: {err.strerror or err}") from err
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise MapError(path, "empty file")
    delim = ";" if lines[0].count(";") > lines[0].count(",") else ","
    rows = list(csv.reader(lines, delimiter=delim))
    header = [h.strip() for h in rows[0]]
    missing = [c for c in cmap.channels() if c not in header]
    if missing:
        raise MapError(path, f"column(s) {', '.join(missing)} named by {cmap.path.name} not "
                             f"in the header")
    def number(text: str) -> float:
        text = text.strip().replace(",", ".") if delim == ";" else text.strip()
        return float(text) if text else np.nan

    columns = {}
    for name in cmap.channels():
        j = header.index(name)
        try:
            columns[name] = np.array([number(r[j]) for r in rows[1:]])
        except (ValueError, IndexError) as err:
            raise MapError(path, f"column {name}: {err}") from err
    t = columns.pop(cmap.time.channels[0]) * cmap.time.scale
    return t, columns


def import_mapped(path: str | Path, out_bag: str | Path, cmap: ChannelMap, *,
                  storage: str = "mcap", time_offset_ns: int = 0) -> tuple[int, float]:
    """Import ``path`` (MDF4 or CSV) through ``cmap`` into a new RigState bag.

    Returns (messages written, time span of the samples [s]).
    """
    path, out = Path(path), Path(out_bag)
    if out.exists():
        raise BagExistsError(out, "output exists already; bags are never overwritten")
    reader = read_mdf_channels if path.suffix.lower() in MDF_SUFFIXES else read_csv_channels
    t, columns = reader(path, cmap)
    custom = {"clutch_ros.importer": "mdf4" if reader is read_mdf_channels else "csv-map",
              "clutch_ros.source": path.name, "clutch_ros.map": cmap.path.name}
    writer = write_rig_states(out, samples(cmap, t, columns, time_offset_ns), storage=storage,
                              custom_data=custom)
    span = ((writer.last_ns or 0) - (writer.first_ns or 0)) * 1e-9
    return sum(writer.written.values()), span
