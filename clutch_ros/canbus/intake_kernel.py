"""The per-frame loop of the can_bridge's receive path, compiled in :mod:`.intake`.

These are plain Python functions over numpy arrays; :mod:`clutch_ros.canbus.intake` compiles
them with numba (``njit``) and owns the arrays. :func:`scan` counts foreign identifiers (not
in the DBC) and does, for a run of *clean* rig frames, exactly what
:meth:`~clutch_ros.canbus.assembler.RigStateAssembler.feed_frame` followed by the
can_bridge's pacing (``ReceiveSide._on_frames``: ``PublishPacer``'s ``fallback_due`` and
``trigger_held``) do, without a Python object per frame, and stops:

* *before* the first frame that is not clean -- an error, remote or FD frame, an invalid
  identifier or DLC, a DBC frame outside the compiled tables (the pump request, a frame
  whose signals the tables cannot decode), a wrong length, a wrong checksum, a value
  outside its DBC range, a non-finite time -- which the caller then hands to the Python path,
  so everything rare keeps one implementation;
* *after* a frame at which the pacer publishes (the trigger when the cap allows it, or a
  fallback frame when the trigger is missing), so the caller publishes the sample as of that
  frame.

The arithmetic is :class:`~clutch_ros.canbus.fastdecode.FastDecoder`'s, in the same order:
``raw = (bits >> start) & mask``, two's complement at ``sign``, ``raw * scale + offset`` (or
``raw`` for the identity), then ``* factor`` unless the factor is 1; ranges compared as
``lo <= value <= hi``. Signals of at most 52 bits only (the tables refuse others), so every
raw value is exact as a float64, as it is as a Python int.

Layouts (the index constants below name the columns):

* ``slots`` int64 (K, 10): per frame key of the tables -- key, compiled, length, E2E,
  number of fields, counter field (-1: none), fills the sample, fallback key, ranges, writes;
* ``fint`` int64 (K, F, 3): start, mask, sign per field; ``fflt`` float64 (K, F, 4): scale,
  offset, has offset (1.0/0.0), factor; ``rint`` int64 (K, R): field of each range;
  ``rflt`` float64 (K, R, 2): low, high; ``cycle`` float64 (K): the frame's cycle time [s]
  (0: none);
* state: ``counts`` int64 (7): frames, data frames, decoded frames, dropped, repeats,
  foreign frames, foreign keys (added to the assembler's counters by the caller); the foreign
  keys in the order first seen, ``unknown_keys`` int64 (U), and their frames,
  ``unknown_counts`` int64 (U) (a run stops when U keys are there); ``per_id`` int64 (K);
  the rolling counters' ``ctr_has`` (K, bool as int64), ``ctr_stamp`` (K), ``ctr_val`` (K);
  the newest decoded time ``newest`` float64 (2): has, time; per slot the newest fill
  ``fill_stamp`` (K), ``fill_seq`` int64 (K: order of the newest fill, -1: none in this run);
* the sample's fields (:class:`~clutch_ros.rigstate.RigSample`, one entry per scalar and per
  array element): ``wint`` int64 (K, W, 3) per write of a slot -- target entry, field, kind
  (``W_*``); ``wflt`` float64 (K, W, 2): mult, offset; ``faults`` int64 (K, 7): the field of
  each ``PumpSts_Flt*`` signal (-1: not in the frame); ``live`` float64 (T): the newest value
  written to each entry in this run, ``written`` int64 (T) set where one was;
* ``pacer`` float64 (8): tokens, last, flowing since, last frame (NaN: None), pending, rate
  [1/s], burst, active (1.0: the bridge publishes); ``trigger`` is the trigger's frame key
  (-1: None).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from clutch_ros.model.arraytypes import BoolArray, FloatArray, IntArray

__all__ = ["C_TOTAL", "LOOP_FUNCTIONS", "MAX_BITS", "S_KEY", "crc8", "scan"]

# slots columns
(S_KEY, S_OK, S_LEN, S_E2E, S_NFIELDS, S_COUNTER, S_FILL, S_FALLBACK, S_NRANGES,
 S_NWRITES) = range(10)
# kinds of writes into the sample: mult * value + offset, bool, int, the pump's fault bits
W_VALUE, W_FLAG, W_INT, W_FAULTS = range(4)
# counts
C_TOTAL, C_DATA, C_DECODED, C_DROPPED, C_REPEATS, C_UNKNOWN, C_UNKNOWN_KEYS = range(7)
# pacer
P_TOKENS, P_LAST, P_FLOWING, P_LAST_FRAME, P_PENDING, P_RATE, P_BURST, P_ACTIVE = range(8)
#: widest signal the tables take: its raw value is exact as a float64
MAX_BITS = 52
#: the functions :mod:`clutch_ros.canbus.intake` compiles (callees first)
LOOP_FUNCTIONS = ("crc8", "_slot", "_value", "scan")


def crc8(data: NDArray[np.uint8], start: int, stop: int, table: IntArray) -> int:
    """CRC-8 SAE J1850 of ``data[start:stop]`` (``dbc.crc8_sae_j1850``'s table)."""
    crc = 0xFF
    for i in range(start, stop):
        crc = table[crc ^ data[i]]
    return crc ^ 0xFF


def _slot(slots: IntArray, key: int) -> int:
    """Row of frame ``key`` in ``slots`` (-1: none; a linear search over ~10 rows)."""
    for s in range(slots.shape[0]):
        if slots[s, S_KEY] == key:
            return s
    return -1


def _value(bits: np.uint64, fint: IntArray, fflt: FloatArray, s: int, f: int) -> float:
    """SI value of field ``f`` of slot ``s`` from the payload's little-endian ``bits``."""
    raw = (bits >> np.uint64(fint[s, f, 0])) & np.uint64(fint[s, f, 1])
    sign = np.uint64(fint[s, f, 2])
    value = float(np.int64(raw))
    if sign != 0 and (raw & sign) != 0:
        value = float(np.int64(raw) - np.int64(sign << np.uint64(1)))
    if fflt[s, f, 2] != 0.0:
        value = value * fflt[s, f, 0] + fflt[s, f, 1]
    if fflt[s, f, 3] != 1.0:
        value = value * fflt[s, f, 3]
    return value


def scan(stamp: FloatArray, ident: IntArray, ext: BoolArray, remote: BoolArray,
         error: BoolArray, fd: BoolArray, dlc: IntArray, size: IntArray,
         data: NDArray[np.uint8], offset: IntArray, i0: int,
         slots: IntArray, fint: IntArray, fflt: FloatArray, rint: IntArray, rflt: FloatArray,
         cycle: FloatArray, crc_table: IntArray, wint: IntArray, wflt: FloatArray,
         faults: IntArray, counts: IntArray, per_id: IntArray, ctr_has: IntArray,
         ctr_stamp: FloatArray, ctr_val: IntArray, newest: FloatArray, fill_stamp: FloatArray,
         fill_seq: IntArray, live: FloatArray, written: IntArray, unknown_keys: IntArray,
         unknown_counts: IntArray, seq: int, pacer: FloatArray,
         trigger: int) -> tuple[int, int, int]:
    """Consume clean frames from ``i0`` on; return ``(next index, publishing key or -1, seq)``.

    Frame ``i``: ``stamp`` [s], ``ident``, flags ``ext``/``remote``/``error``/``fd``, ``dlc``,
    payload ``data[offset[i]:offset[i] + size[i]]``. See the module docstring.
    """
    n = stamp.shape[0]
    i = i0
    while i < n:
        if error[i] or remote[i] or fd[i] or not math.isfinite(stamp[i]):
            return i, -1, seq
        ident_i, nbytes = ident[i], size[i]
        if ident_i < 0 or ident_i >= (0x20000000 if ext[i] else 0x800) or nbytes > 8 \
                or dlc[i] != nbytes:
            return i, -1, seq
        key = ident_i | 0x80000000 if ext[i] else ident_i
        s = _slot(slots, key)
        if s < 0:  # a foreign identifier: counted (per key, the first seen first), no more
            n_keys = counts[C_UNKNOWN_KEYS]
            j = 0
            while j < n_keys and unknown_keys[j] != key:
                j += 1
            if j == n_keys:
                if n_keys == unknown_keys.shape[0]:
                    return i, -1, seq
                unknown_keys[j], unknown_counts[j] = key, 0
                counts[C_UNKNOWN_KEYS] += 1
            unknown_counts[j] += 1
            counts[C_TOTAL] += 1
            counts[C_DATA] += 1
            counts[C_UNKNOWN] += 1
            i += 1
            continue
        if slots[s, S_OK] == 0 or nbytes != slots[s, S_LEN]:
            return i, -1, seq
        start = offset[i]
        if slots[s, S_E2E] != 0 and (nbytes < 1 or crc8(data, start + 1, start + nbytes,
                                                        crc_table) != data[start]):
            return i, -1, seq
        bits = np.uint64(0)
        for b in range(nbytes):
            bits |= np.uint64(data[start + b]) << np.uint64(8 * b)
        for r in range(slots[s, S_NRANGES]):
            value = _value(bits, fint, fflt, s, rint[s, r])
            if not (rflt[s, r, 0] <= value <= rflt[s, r, 1]):
                return i, -1, seq
        now = stamp[i]
        # -- the assembler (feed_frame of a decoded rig frame) --
        counts[C_TOTAL] += 1
        counts[C_DATA] += 1
        counts[C_DECODED] += 1
        per_id[s] += 1
        field = slots[s, S_COUNTER]
        if field >= 0:
            counter = int(_value(bits, fint, fflt, s, field))
            had, last_stamp, last = ctr_has[s], ctr_stamp[s], ctr_val[s]
            ctr_has[s], ctr_stamp[s], ctr_val[s] = 1, now, counter
            if had != 0 and not (cycle[s] != 0.0 and now - last_stamp > 16.0 * cycle[s]):
                if counter == last:
                    counts[C_REPEATS] += 1
                else:
                    counts[C_DROPPED] += (counter - last - 1) % 16
        if newest[0] == 0.0 or now > newest[1]:
            newest[0], newest[1] = 1.0, now
        if slots[s, S_FILL] != 0:
            for w in range(slots[s, S_NWRITES]):
                target, kind = wint[s, w, 0], wint[s, w, 2]
                if kind == W_FAULTS:
                    fault_bits = 0
                    for j in range(faults.shape[1]):
                        if faults[s, j] >= 0 and _value(bits, fint, fflt, s, faults[s, j]) != 0.0:
                            fault_bits |= 1 << j
                    live[target] = fault_bits
                else:
                    value = _value(bits, fint, fflt, s, wint[s, w, 1])
                    if kind == W_VALUE:
                        live[target] = wflt[s, w, 0] * value + wflt[s, w, 1]
                    elif kind == W_FLAG:
                        live[target] = 1.0 if value != 0.0 else 0.0
                    else:
                        live[target] = value
                written[target] = 1
            fill_stamp[s], fill_seq[s] = now, seq
            seq += 1
        i += 1
        # -- the pacer (ReceiveSide._on_frames) --
        if pacer[P_ACTIVE] == 0.0 or trigger < 0:
            continue
        at = newest[1]
        rate = pacer[P_RATE]
        if key != trigger:
            if slots[s, S_FALLBACK] == 0:
                continue
            last_frame = pacer[P_LAST_FRAME]
            pacer[P_LAST_FRAME] = at
            flowing = pacer[P_FLOWING]
            if (math.isnan(flowing) or at < flowing or math.isnan(last_frame)
                    or (at - last_frame) * rate > 1.0):
                pacer[P_FLOWING] = flowing = at
            if (at - flowing) * rate > 2.0:
                return i, key, seq
            continue
        tokens, last = pacer[P_TOKENS], pacer[P_LAST]
        earned = tokens if math.isnan(last) else min(pacer[P_BURST],
                                                     tokens + max(0.0, at - last) * rate)
        if earned >= 1.0:
            return i, key, seq
        pacer[P_TOKENS], pacer[P_LAST], pacer[P_FLOWING], pacer[P_PENDING] = (
            earned, at, math.nan, 1.0)
    return i, -1, seq
