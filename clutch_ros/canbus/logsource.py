"""Read CAN log files (Vector ASC/BLF or any python-can format) through the rig decode path.

:class:`LogSource` opens a log with :func:`can.LogReader` (format picked by suffix: ``.asc``,
``.blf``, ``.trc``, ``.log``, ``.csv``, ``.db``, ``.mf4``, and ``.gz`` of those), and replays
it at original timing (:class:`can.MessageSync`) or as fast as possible into a
:class:`~clutch_ros.canbus.assembler.RigStateAssembler`, the same object the live bus feeds.
Unknown identifiers, error and remote frames are counted there, never raised. A file that
is missing, of unknown format, corrupt or truncated raises :class:`LogFileError` naming it.

Truncation checks (``check_complete=True``): a BLF whose header announces more bytes than
the file holds, and an ASC without its closing ``End TriggerBlock`` line (Vector writes it
when a measurement stops), are reported as truncated.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol

import can
from can.io.player import MESSAGE_READERS

from clutch_ros.canbus.assembler import RigStateAssembler
from clutch_ros.canbus.errors import LogFileError
from clutch_ros.rigstate import RigSample

__all__ = ["Assembler", "LogSource", "supported_suffixes"]


class Assembler(Protocol):
    """What :meth:`LogSource.samples` needs: a :class:`RigStateAssembler` or a stand-in."""

    def feed(self, msg: can.Message) -> object:
        """Take one frame."""

    def snapshot(self, now: float | None = None) -> RigSample:
        """Return the sample assembled so far, aged at ``now``."""


def supported_suffixes() -> tuple[str, ...]:
    """Return the log file suffixes python-can can read here (``.gz`` wraps any of them)."""
    return (*sorted(MESSAGE_READERS), ".gz")


class LogSource:
    """One CAN log file as a source of frames and RigSamples.

    ``realtime``: replay at the recorded timing (pauses longer than ``skip`` [s] are cut to
    ``skip``); otherwise as fast as possible. ``check_complete``: detect truncated ASC/BLF
    (see module docstring). ``reader_kwargs`` go to the python-can reader (e.g.
    ``relative_timestamp=False`` for ASC). Opening is lazy: errors appear when iterating;
    call :meth:`check` to validate up front.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        realtime: bool = False,
        skip: float = 60.0,
        check_complete: bool = True,
        **reader_kwargs: Any,
    ) -> None:
        self.path = Path(path)
        self.realtime = realtime
        self.skip = skip
        self.check_complete = check_complete
        self.reader_kwargs = reader_kwargs
        #: frames read so far by :meth:`frames`
        self.frames_read = 0
        #: bus timestamps [s] of the first and last frame read (None before any)
        self.first_time: float | None = None
        self.last_time: float | None = None

    def _error(self, what: str, err: BaseException | None = None) -> LogFileError:
        detail = f": {type(err).__name__}: {err}" if err is not None else ""
        return LogFileError(f"{self.path}: {what}{detail}")

    def check(self) -> None:
        """Validate existence, format and completeness; raises :class:`LogFileError`."""
        if not self.path.is_file():
            raise self._error("CAN log file not found")
        suffixes = [s.lower() for s in self.path.suffixes]
        suffix = suffixes[-1] if suffixes else ""
        if suffix == ".gz":
            suffix = suffixes[-2] if len(suffixes) >= 2 else ""
        elif not self.check_complete:
            pass
        elif suffix == ".blf":
            self._check_blf()
        elif suffix == ".asc":
            self._check_asc()
        if suffix not in MESSAGE_READERS:
            raise self._error(
                f"unsupported CAN log format {suffix!r}; supported: "
                f"{', '.join(supported_suffixes())}"
            )

    def _check_blf(self) -> None:
        try:
            with self.path.open("rb") as fh:
                header = fh.read(144)
        except OSError as err:
            raise self._error("cannot read", err) from err
        if len(header) < 72 or header[:4] != b"LOGG":
            raise self._error("not a BLF file (bad header)")
        declared = int.from_bytes(header[16:24], "little")
        actual = self.path.stat().st_size
        if declared and actual < declared:
            raise self._error(f"truncated BLF ({actual} of {declared} bytes)")

    def _check_asc(self) -> None:
        try:
            with self.path.open("rb") as fh:
                fh.seek(max(0, self.path.stat().st_size - 512))
                tail = fh.read().decode("latin-1").strip().lower()
        except OSError as err:
            raise self._error("cannot read", err) from err
        if not tail.endswith("end triggerblock"):
            raise self._error("truncated ASC (no closing 'End TriggerBlock' line)")

    def frames(self, stop: threading.Event | None = None) -> Iterator[can.Message]:
        """Yield the log's frames (at recorded timing if ``realtime``) until the end or ``stop``.

        Raises :class:`LogFileError` for unreadable, corrupt or truncated files.
        """
        self.check()
        try:
            reader = can.LogReader(self.path, **self.reader_kwargs)
        except Exception as err:  # ValueError (format), BLFParseError, OSError, struct.error
            raise self._error("cannot open CAN log", err) from err
        try:
            source = (
                can.MessageSync(reader, timestamps=True, skip=self.skip)
                if self.realtime
                else reader
            )
            iterator = iter(source)
            while stop is None or not stop.is_set():
                try:
                    msg = next(iterator)
                except StopIteration:
                    break
                except Exception as err:  # corrupt content: parse errors of any kind
                    raise self._error(
                        f"corrupt CAN log after {self.frames_read} frames", err
                    ) from err
                self.frames_read += 1
                if self.first_time is None:
                    self.first_time = msg.timestamp
                self.last_time = msg.timestamp
                yield msg
        finally:
            try:
                reader.stop()
            except Exception:  # closing a broken file must not hide the real error
                pass

    def feed(self, assembler: RigStateAssembler, stop: threading.Event | None = None) -> int:
        """Feed every frame into ``assembler``; return the number of frames read."""
        count = 0
        for msg in self.frames(stop):
            assembler.feed(msg)
            count += 1
        return count

    def samples(
        self,
        assembler: Assembler,
        period: float,
        stop: threading.Event | None = None,
        max_gap: float = 1.0,
    ) -> Iterator[RigSample]:
        """Feed the log into ``assembler`` and yield a :class:`RigSample` every ``period`` [s].

        Sample k is taken at log time ``t0 + k * period`` from the frames before it (``t0``
        = first frame's timestamp), aged against that time. Across gaps longer than
        ``max_gap`` [s] the sample grid jumps forward (one stale sample, not thousands). A
        last sample is taken at the last frame's time.
        """
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"period must be > 0 s, got {period!r}")
        # Grid point k is t0 + k * period, computed (not accumulated), and a frame within
        # ``eps`` before a grid point counts as on it: logs store times to 1 us or 10 ns, so
        # frames sent exactly on the grid must not fall on either side of it by rounding
        # (that would give two samples with the same newest frame, then none).
        eps = min(1e-6, 1e-3 * period)
        t0: float | None = None
        k = 1
        for msg in self.frames(stop):
            stamp = msg.timestamp + eps
            if t0 is None:
                t0 = msg.timestamp
            elif stamp >= t0 + k * period:
                if stamp - (t0 + k * period) > max_gap:
                    yield assembler.snapshot(t0 + k * period)
                    k += math.floor((stamp - (t0 + k * period)) / period)
                while stamp >= t0 + k * period:
                    yield assembler.snapshot(t0 + k * period)
                    k += 1
            assembler.feed(msg)
        if self.last_time is not None:
            yield assembler.snapshot(self.last_time)
