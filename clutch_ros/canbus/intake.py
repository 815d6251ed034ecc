"""The can_bridge's clean rig frames decoded, assembled and paced in compiled code.

Live, the can_bridge spends most of its CPU on Python per frame: ~2,400 rig frames/s in the
demo, each decoded (:class:`~clutch_ros.canbus.fastdecode.FastDecoder`), written into the
live sample and paced (:meth:`RigStateAssembler.feed_frame`, ``ReceiveSide._on_frames``).
:class:`CompiledIntake` runs that per-frame loop for a batch of frames in one call of
:func:`clutch_ros.canbus.intake_kernel.scan` (numba) and hands back to Python only:

* once per batch, what the run of frames changed (counters, rolling counters, the newest
  time, the live sample's fields in the order the frames wrote them), which the assembler
  applies itself (:meth:`RigStateAssembler.apply_frames`: its state stays in one class);
* every frame that is neither a clean rig frame nor a foreign one (errors, bad checksums,
  values out of range...: :mod:`~clutch_ros.canbus.intake_kernel`), which the caller feeds
  through the Python path, so the rare cases keep one implementation;
* every frame at which the pacer publishes, so the caller publishes the sample as of it.

The result is the Python path's, frame for frame: the same counters, samples, pacer state
and publications (``tests/nodes/test_can_bridge_intake.py`` runs both on the same traffic).

Compilation: numba compiles :mod:`~clutch_ros.canbus.intake_kernel` when the first
:class:`CompiledIntake` is made (``cache=True``: ~4 s once per install, which
``tools/bootstrap.sh`` does with :func:`clutch_ros.canbus.udp_columns.warm_up`; then ~1 s
to load from the cache in the folder of :func:`clutch_ros.model.kernel.numba_cache_dir`).
When numba is missing or fails, the reason is logged once and kept in
:func:`unavailable_reason`, :attr:`CompiledIntake.ready` is
False, and the caller uses the Python path.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Collection, Sequence
from types import ModuleType
from typing import Any, NamedTuple, cast

import numpy as np

from clutch_ros.canbus import intake_kernel as kern
from clutch_ros.canbus.assembler import PUMP_FAULTS, SPECIAL_FIELDS, RigStateAssembler
from clutch_ros.canbus.batch import RawFrame
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.canbus.dbc import crc8_table

__all__ = ["Columns", "CompiledIntake", "columns", "compiled_functions", "compress", "frame_at",
           "take", "unavailable_reason", "warm_up"]

_log = logging.getLogger(__name__)
_LOCK = threading.Lock()
#: scan: the compiled kernel once built; reason: why it cannot be
_state: dict[str, Any] = {"scan": None, "reason": None}


class Columns(NamedTuple):
    """A batch of :data:`~clutch_ros.canbus.batch.RawFrame` as arrays (one per field).

    ``data`` holds the payloads back to back, frame ``i``'s at ``offset[i]`` for ``size[i]``
    bytes.
    """

    stamp: np.ndarray
    ident: np.ndarray
    ext: np.ndarray
    remote: np.ndarray
    error: np.ndarray
    fd: np.ndarray
    dlc: np.ndarray
    size: np.ndarray
    data: np.ndarray
    offset: np.ndarray


def columns(frames: Sequence[RawFrame]) -> Columns | None:
    """Return the frames as :class:`Columns` (None: a field no int64 holds; Python path)."""
    n = len(frames)
    if not n:
        return None
    stamp, ident, ext, remote, error, fd, dlc, data = zip(*frames, strict=True)
    try:
        size = np.fromiter(map(len, data), np.int64, n)
        offset = np.zeros(n, np.int64)
        np.cumsum(size[:-1], out=offset[1:])
        payload = np.frombuffer(b"".join(data) or b"\0", np.uint8)
        return Columns(np.array(stamp, np.float64), np.array(ident, np.int64),
                       np.array(ext, np.bool_), np.array(remote, np.bool_),
                       np.array(error, np.bool_), np.array(fd, np.bool_),
                       np.array(dlc, np.int64), size, payload, offset)
    except (OverflowError, TypeError, ValueError):
        return None


def unavailable_reason() -> str | None:
    """Why the compiled intake cannot be used (None while it can, or before it was tried)."""
    reason: str | None = _state["reason"]
    return reason


def compiled_functions(module: ModuleType, names: Sequence[str],
                       warm_up: Callable[[Callable[..., Any]], None]) -> Callable[..., Any] | None:
    """Compile ``module``'s functions ``names`` with numba; return the last, or None.

    Callees first: each is replaced in the module by its compiled self, so the functions
    that call it compile against it. ``warm_up(last)`` calls it once, so numba compiles it
    (or loads it from its cache, ``cache=True``) now. None, with the reason logged once and
    kept in :func:`unavailable_reason`, when numba is missing or any step fails.
    """
    with _LOCK:
        if _state["reason"] is not None:
            return None
        from clutch_ros.model.kernel import numba_cache_dir
        os.environ.setdefault("NUMBA_CACHE_DIR", numba_cache_dir())
        try:
            import numba

            jit = numba.njit(cache=True, nogil=True)
            for name in names:  # compiled where they live (their globals)
                func = getattr(module, name)
                if not hasattr(func, "py_func"):
                    setattr(module, name, jit(func))
            last: Callable[..., Any] = getattr(module, names[-1])
            warm_up(last)
        except Exception as err:  # noqa: BLE001 - any failure means: the Python path
            _state["reason"] = f"numba unavailable ({type(err).__name__}: {err})"
            _log.warning("compiled CAN intake: %s; Python path", _state["reason"])
            return None
        return last


def _compiled() -> Callable[..., tuple[int, int, int]] | None:
    """Return the compiled :func:`~clutch_ros.canbus.intake_kernel.scan` (None: unavailable)."""
    if _state["scan"] is None and _state["reason"] is None:
        _state["scan"] = compiled_functions(kern, kern.LOOP_FUNCTIONS, _warm_up)
    return cast("Callable[..., tuple[int, int, int]] | None", _state["scan"])


def take(cols: Columns, which: slice | np.ndarray) -> Columns:
    """Return the frames ``which`` (a slice, a mask) of ``cols``: views where numpy can."""
    return Columns(cols.stamp[which], cols.ident[which], cols.ext[which], cols.remote[which],
                   cols.error[which], cols.fd[which], cols.dlc[which], cols.size[which],
                   cols.data, cols.offset[which])


def compress(cols: Columns, keep: np.ndarray) -> Columns | None:
    """Return the frames of ``cols`` where ``keep`` is True (None: none)."""
    return take(cols, keep) if keep.any() else None


def frame_at(cols: Columns, i: int) -> RawFrame:
    """Return frame ``i`` of ``cols`` as a :data:`~clutch_ros.canbus.batch.RawFrame`."""
    start = int(cols.offset[i])
    return (float(cols.stamp[i]), int(cols.ident[i]), bool(cols.ext[i]), bool(cols.remote[i]),
            bool(cols.error[i]), bool(cols.fd[i]), int(cols.dlc[i]),
            cols.data[start:start + int(cols.size[i])].tobytes())


def warm_up() -> str | None:
    """Compile the kernel now (into numba's cache); return why it cannot be, else None.

    :func:`clutch_ros.canbus.udp_columns.warm_up` (``tools/bootstrap.sh`` after an install)
    calls it, so a bridge's first start loads the compiled code instead of compiling it.
    """
    _compiled()
    return unavailable_reason()


def _warm_up(scan: Callable[..., tuple[int, int, int]]) -> None:
    """Call ``scan`` once with every argument of the types :meth:`CompiledIntake.run` uses."""
    cols = columns([(0.0, 0x7FF, False, False, False, False, 0, b"")])
    assert cols is not None
    i8, f8 = np.int64, np.float64
    scan(*cols, 0, np.zeros((1, 10), i8), np.zeros((1, 1, 3), i8), np.zeros((1, 1, 4), f8),
         np.zeros((1, 1), i8), np.zeros((1, 1, 2), f8), np.zeros(1, f8), np.zeros(256, i8),
         np.zeros((1, 1, 3), i8), np.zeros((1, 1, 2), f8), np.zeros((1, 7), i8),
         np.zeros(7, i8), np.zeros(1, i8), np.zeros(1, i8), np.zeros(1, f8), np.zeros(1, i8),
         np.zeros(2, f8), np.zeros(1, f8), np.zeros(1, i8), np.zeros(1, f8), np.zeros(1, i8),
         np.zeros(1, i8), np.zeros(1, i8), 0, np.zeros(8, f8), -1)


class _Tables(NamedTuple):
    """The kernel's tables of an assembler (:mod:`~clutch_ros.canbus.intake_kernel`)."""

    scan: tuple[np.ndarray, ...]  # slots, fint, fflt, rint, rflt, cycle, crc table
    writes: tuple[np.ndarray, ...]  # wint, wflt, faults
    targets: list[tuple[str, int, int]]  # per entry of ``live``: field, element (-1), kind
    slip: tuple[list[int], list[int]]  # slots deriving slip_speed, slots writing it
    torque_valid: tuple[list[int], list[int]]  # slots deriving has_measured_torque, writing it


class CompiledIntake:
    """:meth:`run` feeds and paces a batch's clean frames (module docstring).

    ``assembler`` and ``pacer``: the can_bridge's; ``python_keys``: frame keys always left to
    the Python path (the pump request: the bridge counts a foreign one). The tables are
    built from the assembler's DBC and signal map once; its pacer's trigger and rate are read
    at every :meth:`run`, so a changed ``bridge.publish_on`` or ``bridge.rate`` applies at
    once. The kernel is built (or loaded from numba's cache) here, before the caller's
    threads run: ~1 s with the cache, ~4 s without (numba's import and compilation hold
    the GIL, and beside a live receive thread they delayed its rig_state by tens of ms).
    """

    def __init__(self, assembler: RigStateAssembler, pacer: PublishPacer,
                 python_keys: Sequence[int] = ()) -> None:
        self._asm, self._pacer = assembler, pacer
        self._t = _tables(assembler, pacer.fallback, frozenset(python_keys))
        self._keys = [int(k) for k in self._t.scan[0][:, kern.S_KEY]]
        k, n_targets = len(self._keys), max(len(self._t.targets), 1)
        self._counts = np.zeros(7, np.int64)
        self._unknown_keys, self._unknown_counts = np.zeros(64, np.int64), np.zeros(64, np.int64)
        self._per_id = np.zeros(k, np.int64)
        self._ctr_has, self._ctr_stamp, self._ctr_val = (np.zeros(k, np.int64),
                                                         np.zeros(k), np.zeros(k, np.int64))
        self._newest = np.zeros(2)
        self._fill_stamp, self._fill_seq = np.zeros(k), np.full(k, -1, np.int64)
        self._live, self._written = np.zeros(n_targets), np.zeros(n_targets, np.int64)
        self._pacer_state = np.zeros(8)
        #: frames the kernel took (the others went to the Python path)
        self.taken = 0
        self._scan = _compiled()

    columns = staticmethod(columns)

    @property
    def ready(self) -> bool:
        """True when the compiled kernel can run (False: numba unavailable; the Python path)."""
        return self._scan is not None

    def run(self, cols: Columns, start: int, active: bool) -> tuple[int, int]:
        """Feed (and pace, when ``active``) the clean frames of ``cols`` from ``start`` on.

        Returns ``(next, key)``: the frames before ``next`` were consumed; ``key`` >= 0: the
        last of them is to publish (the caller calls ``pacer.on_frame(key, ...)`` through its
        publication); else frame ``next`` (if any) is for the Python path. Call with the lock
        that guards the pacer held (the can_bridge's node lock); takes the assembler's.
        """
        scan = self._scan
        assert scan is not None  # (ready)
        asm, pacer = self._asm, self._pacer
        with asm.lock:
            self._load(asm, pacer, active)
            nxt, key, _ = scan(*cols, start, *self._t.scan, *self._t.writes,
                               self._counts, self._per_id, self._ctr_has, self._ctr_stamp,
                               self._ctr_val, self._newest, self._fill_stamp, self._fill_seq,
                               self._live, self._written, self._unknown_keys,
                               self._unknown_counts, 0, self._pacer_state,
                               -1 if pacer.trigger is None else pacer.trigger)
            if nxt > start:
                self._store(asm, pacer)
                self.taken += nxt - start
        return int(nxt), int(key)

    def _load(self, asm: RigStateAssembler, pacer: PublishPacer, active: bool) -> None:
        self._counts[:] = 0
        self._per_id[:] = 0
        self._fill_seq[:] = -1
        self._written[:] = 0
        counters, newest = asm.counter_state(self._keys)
        # whole arrays at once: an element assignment each costs more
        self._ctr_has[:] = [entry is not None for entry in counters]
        self._ctr_stamp[:] = [entry[0] if entry is not None else 0.0 for entry in counters]
        self._ctr_val[:] = [entry[1] if entry is not None else 0 for entry in counters]
        self._newest[:] = (0.0, 0.0) if newest is None else (1.0, newest)
        pacer.export_state(self._pacer_state)
        self._pacer_state[kern.P_ACTIVE] = 1.0 if active else 0.0

    def _store(self, asm: RigStateAssembler, pacer: PublishPacer) -> None:
        keys, counts = self._keys, self._counts.tolist()
        n_unknown = counts[kern.C_UNKNOWN_KEYS]
        unknown = zip(self._unknown_keys[:n_unknown].tolist(),
                      self._unknown_counts[:n_unknown].tolist(), strict=True)
        per_id, has = self._per_id.tolist(), self._ctr_has.tolist()
        stamps, values = self._ctr_stamp.tolist(), self._ctr_val.tolist()
        per_key = [(keys[s], n, (stamps[s], values[s]) if has[s] else None)
                   for s, n in enumerate(per_id) if n]
        newest = self._newest.tolist()
        seq = self._fill_seq.tolist()
        fields: list[tuple[str, int, float | int | bool]] = []
        derive, filled = (False, False), []
        if max(seq) >= 0:
            live, targets = self._live.tolist(), self._t.targets
            for t, written in enumerate(self._written.tolist()):
                if written:
                    name, element, kind = targets[t]
                    value = live[t]
                    fields.append((name, element, value if element >= 0 or kind == kern.W_VALUE
                                   else bool(value) if kind == kern.W_FLAG else int(value)))
            # derived as the last frame's fill left them
            slip, valid = self._t.slip, self._t.torque_valid
            derive = (_last(seq, slip[0]) > _last(seq, slip[1]),
                      _last(seq, valid[0]) > _last(seq, valid[1]))
            fill_stamps = self._fill_stamp.tolist()
            filled = [(keys[s], fill_stamps[s]) for s, order in enumerate(seq) if order >= 0]
        asm.apply_frames((counts[kern.C_TOTAL], counts[kern.C_DATA], counts[kern.C_DECODED],
                          counts[kern.C_DROPPED], counts[kern.C_REPEATS]),
                         unknown, per_key, newest[1] if newest[0] else None, fields, derive,
                         filled)
        pacer.import_state(self._pacer_state)


def _last(seq: list[int], slots: list[int]) -> int:
    """Return the newest fill order among ``slots`` in this run (-1: none filled)."""
    best = -1
    for s in slots:  # (one or two slots: a loop beats max() of a generator)
        if seq[s] > best:
            best = seq[s]
    return best


def _tables(asm: RigStateAssembler, fallback: Collection[int],
            python_keys: frozenset[int]) -> _Tables:
    """Return the kernel's tables of ``asm`` (:mod:`~clutch_ros.canbus.intake_kernel`)."""
    db, map_writes = asm.db, asm.map.writes
    rows = []
    for spec in db.frames:
        key = spec.key
        table = asm.decoder.table(key)
        ok = (table is not None and key not in python_keys and spec.length <= 8
              and all(f[2].bit_length() <= kern.MAX_BITS for f in table[2]))
        rows.append((key, table if ok else None))
    k = len(rows)
    width = max((len(t[2]) for _, t in rows if t is not None), default=1)
    nranges = max((len(t[4]) for _, t in rows if t is not None), default=1)
    nwrites = max((len(w) + 2 for w in map_writes.values()), default=1)
    slots = np.zeros((k, 10), np.int64)
    fint, fflt = np.zeros((k, width, 3), np.int64), np.zeros((k, width, 4))
    rint, rflt = np.zeros((k, max(nranges, 1)), np.int64), np.zeros((k, max(nranges, 1), 2))
    wint, wflt = np.zeros((k, nwrites, 3), np.int64), np.zeros((k, nwrites, 2))
    faults = np.full((k, len(PUMP_FAULTS)), -1, np.int64)
    cycle = np.zeros(k)
    counter_of = {s.key: s.counter_signal for s in db.frames}
    targets: dict[tuple[str, int], int] = {}
    kinds: list[tuple[str, int, int]] = []
    slip: tuple[list[int], list[int]] = ([], [])
    torque_valid: tuple[list[int], list[int]] = ([], [])

    def target(name: str, element: int, kind: int) -> int:
        if (name, element) not in targets:
            targets[name, element] = len(kinds)
            kinds.append((name, element, kind))
        return targets[name, element]

    for s, (key, table) in enumerate(rows):
        slots[s, kern.S_KEY] = key
        cycle[s] = asm.cycle_time(key) or 0.0
        if table is None:
            continue
        _name, length, fields, e2e, ranges = table
        names = [f[0] for f in fields]
        slots[s, kern.S_OK], slots[s, kern.S_LEN], slots[s, kern.S_E2E] = 1, length, int(e2e)
        slots[s, kern.S_NFIELDS], slots[s, kern.S_NRANGES] = len(fields), len(ranges)
        counter = counter_of.get(key)
        slots[s, kern.S_COUNTER] = names.index(counter) if counter else -1
        slots[s, kern.S_FALLBACK] = key in fallback
        for f, (_sig, start, mask, sign, scale, offset, factor) in enumerate(fields):
            fint[s, f] = (start, mask, sign)
            fflt[s, f] = (scale, 0.0 if offset is None else offset,
                          0.0 if offset is None else 1.0, factor)
        for r, (sig, lo, hi) in enumerate(ranges):
            rint[s, r], rflt[s, r] = names.index(sig), (lo, hi)
        writes = map_writes.get(key)
        if writes is None:
            continue
        slots[s, kern.S_FILL] = 1
        # the writes of the assembler's filler (assembler._filler), in its order
        by_key = {w.key: w for w in writes}
        plan = [(target(w.field, -1, kern.W_VALUE), w.signal, w.mult, w.offset, kern.W_VALUE)
                for w in writes if w.index is None and w.field not in SPECIAL_FIELDS]
        plan += [(target(w.field, w.index, kern.W_VALUE), w.signal, w.mult, w.offset, kern.W_VALUE)
                 for w in writes if w.index is not None]
        if "has_measured_torque" in by_key:
            plan.append((target("has_measured_torque", -1, kern.W_FLAG),
                         by_key["has_measured_torque"].signal, 1.0, 0.0, kern.W_FLAG))
            torque_valid[1].append(s)
        elif "measured_torque" in by_key:
            torque_valid[0].append(s)
        if "pump_state" in by_key:
            plan.append((target("pump_state", -1, kern.W_INT), by_key["pump_state"].signal,
                         1.0, 0.0, kern.W_INT))
            plan.append((target("pump_faults", -1, kern.W_FAULTS), "", 1.0, 0.0, kern.W_FAULTS))
            for j, sig in enumerate(PUMP_FAULTS):
                faults[s, j] = names.index(sig) if sig in names else -1
        if "slip_speed" in by_key:
            slip[1].append(s)
        elif {"input_speed", "output_speed"} & set(by_key):
            slip[0].append(s)
        slots[s, kern.S_NWRITES] = len(plan)
        for w, (t, sig, mult, offset, kind) in enumerate(plan):
            wint[s, w] = (t, names.index(sig) if sig else -1, kind)
            wflt[s, w] = (mult, offset)
    return _Tables((slots, fint, fflt, rint, rflt, cycle, np.array(crc8_table(), np.int64)),
                   (wint, wflt, faults), kinds, slip, torque_valid)
