"""The estimator over whole series: :func:`estimate_batch`, and :class:`BatchEstimator` by pieces.

:func:`estimate_batch` gives the same result as looping
:meth:`~clutch_ros.model.estimator.ClutchEstimator.update` over arrays (rejected samples raise,
or with ``on_reject="skip"`` give NaN rows): the same validation, the same re-initialisation
after a gap longer than ``max_gap_s``, the same slip filter and pack steps, run per gap-free
segment by the compiled kernel (:func:`~clutch_ros.model.simulate.simulate_columns`) or the
numpy loop (:func:`~clutch_ros.model.simulate.simulate`).

:class:`BatchEstimator` is the same computation fed piece by piece, so a reader can hand over
samples while it is still reading (``clutch replay`` estimates in a second thread while the
bag is read; the kernel runs without the GIL). :func:`estimate_batch` is one feed of the whole
series; a series fed in any number of pieces gives the same arrays: bit for bit with the
kernel's output loop (every sample's arithmetic is scalar and in the same order; all laws
but ``ff_t_printed`` / ``ff_v_printed``), to rounding with the numpy engine and the printed
laws (their vectorised outputs may round the last bit differently at piece ends;
tests/model/test_batch.py states the tolerances). What carries across pieces: the largest
finite stamp so far (rejections), the last accepted sample (gap test, segment continuation),
the filtered slip (the filter continues), the pack state (the segment continues without a
reset) and, with a drivetrain compliance (:mod:`~clutch_ros.model.compliance`), its twist and
the clutch's slip (a new segment starts it as :class:`~clutch_ros.model.estimator
.ClutchEstimator` does).

Shapes: every :class:`EstimateBatch` array is (n,) except ``lamella_normal_force`` and
``spline_friction_force`` (n, N), N = ``params.pack.lamella_count``. Units as
:class:`~clutch_ros.model.estimator.Estimate`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model import kernel
from clutch_ros.model.arraytypes import BoolArray, FloatArray, IntArray
from clutch_ros.model.compliance import capacities, drive_series, reset_state
from clutch_ros.model.errors import DuplicateSample, InputError, NonFiniteSample, OutOfOrderSample
from clutch_ros.model.pack import PackModel
from clutch_ros.model.simulate import simulate, simulate_columns

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.params import ClutchParams

__all__ = ["BatchEstimator", "EstimateBatch", "estimate_batch", "warm_up"]


@dataclass
class EstimateBatch:
    """Estimates over n samples: the fields of :class:`Estimate` as arrays.

    Shapes: (n,) except ``lamella_normal_force`` and ``spline_friction_force`` (n, N).
    ``accepted`` is False for rejected samples (their rows are NaN / False);
    ``spline_law`` is a string.
    """

    stamp: FloatArray
    accepted: BoolArray
    reinitialised: BoolArray
    modelled_torque: FloatArray
    reference_torque: FloatArray
    measured_torque: FloatArray
    torque_accuracy: FloatArray
    friction_coefficient: FloatArray
    lamella_normal_force: FloatArray | None  # None: per_lamella=False
    spline_friction_force: FloatArray | None  # None: per_lamella=False
    front_pressure: FloatArray
    rear_pressure: FloatArray
    pressure_difference: FloatArray
    slip_speed_filtered: FloatArray
    overshoot: BoolArray
    undershoot: BoolArray
    actuating_pressure: FloatArray
    lamella_temperature: FloatArray
    slip_speed: FloatArray
    compression: FloatArray
    spline_correction: FloatArray
    spline_law: str
    clutch_slip_speed: FloatArray | None = None  # ω_c [rad/s]; NaN: compliance off

    def __len__(self) -> int:
        return int(self.stamp.size)


_TORQUE, _REFERENCE, _MU, _FRONT, _REAR, _Z, _TEMP, _FILM, _CORRECTION = range(9)
_SLIP = len(kernel.OUTPUT_COLUMNS)
_CLUTCH_SLIP = _SLIP + 1
_N_COLS = _SLIP + 2
_INPUTS = ("t", "p", "temp", "omega", "meas")
_REJECTED = {1: NonFiniteSample, 2: DuplicateSample, 3: OutOfOrderSample}


def estimate_batch(params: ClutchParams, t: ArrayLike, actuating_pressure: ArrayLike,
                   lamella_temperature: ArrayLike, slip_speed: ArrayLike,
                   measured_torque: ArrayLike | None = None, **options: Any) -> EstimateBatch:
    """Estimate a whole series; identical to looping ``ClutchEstimator.update()``.

    Inputs broadcast to ``t``'s shape (1-D stamps [s]); ``measured_torque`` None means no
    measurement. ``options``: the keyword arguments of :class:`BatchEstimator`
    (``max_gap_s``, ``accuracy_min_torque``, ``overshoot_limit``, ``undershoot_limit``,
    ``on_reject``, ``model``, ``engine``, ``per_lamella``). ``on_reject``: ``"raise"`` (the
    default) raises the first sample's SampleRejected, like an update loop that does not
    catch; ``"skip"`` leaves NaN rows (``accepted`` False), like one that catches and
    continues. ``engine``: the model loop, ``"auto"`` | ``"kernel"`` | ``"numpy"`` (see
    :func:`~clutch_ros.model.simulate.simulate`). ``per_lamella`` False:
    ``lamella_normal_force`` and ``spline_friction_force`` are None (two (n, N) arrays fewer
    for a long series whose per-lamella forces are not used; ``spline_correction`` is still
    computed). One :meth:`BatchEstimator.feed` of the whole series.
    """
    t = np.ascontiguousarray(t, dtype=float)
    if t.ndim != 1:
        raise InputError(f"t must be 1-D, got shape {t.shape}")
    stream = BatchEstimator(params, t.size, **options)
    stream.feed(t, actuating_pressure, lamella_temperature, slip_speed,
                np.nan if measured_torque is None else measured_torque)
    return stream.result()


def warm_up(params: ClutchParams) -> bool:
    """Load the compiled kernel's machine code now; return whether the kernel is in use.

    numba loads a compiled function from its disk cache on the first call (~0.4 s with the
    numba import). A parent that forks workers (``clutch replay --jobs N``) calls this
    first, so every worker inherits the loaded code instead of loading it again. Estimates
    three samples with ``params`` (any law: the loop is one compiled function) and discards
    them.
    """
    if not kernel.available():
        return False
    estimate_batch(params, [0.0, 1e-3, 2e-3], 1e5, np.nan, 1.0, per_lamella=False)
    return True


class BatchEstimator:
    """:func:`estimate_batch` fed piece by piece (module docstring); same arguments.

    Args:
        params: :class:`~clutch_ros.model.params.ClutchParams`.
        capacity: expected number of samples (the arrays grow when more are fed).

    ``feed()`` pieces in stream order, then ``result()`` once. Not thread-safe: one feeder at
    a time (``clutch replay`` feeds from one worker thread, in order).
    """

    def __init__(self, params: ClutchParams, capacity: int = 0, *, max_gap_s: float = 1.0,
                 accuracy_min_torque: float = 1.0, overshoot_limit: float = 1.1,
                 undershoot_limit: float = 0.9, on_reject: str = "raise",
                 model: PackModel | None = None, engine: str = "auto",
                 per_lamella: bool = True) -> None:
        if on_reject not in ("raise", "skip"):
            raise InputError(f"on_reject must be 'raise' or 'skip', got {on_reject!r}")
        kernel.check_engine(engine)
        self.params, self.engine, self.on_reject = params, engine, on_reject
        self.max_gap_s = float(max_gap_s)
        self.accuracy_min_torque = float(accuracy_min_torque)
        self.limits = (float(overshoot_limit), float(undershoot_limit))
        self.model = model
        self.lamellas = params.pack.lamella_count if per_lamella else 0
        self.n = 0  # samples fed
        self._prev_max = -np.inf  # largest finite stamp fed [s]
        self._last: int | None = None  # row of the last accepted sample
        self._drive = np.zeros(2)  # drivetrain compliance: twist [rad], clutch slip [rad/s]
        self._alloc(max(int(capacity), 1))

    def _alloc(self, size: int) -> None:
        self._in: dict[str, FloatArray] = {k: np.empty(size) for k in _INPUTS}
        self.cols: FloatArray = np.empty((_N_COLS, size))
        self.accepted: BoolArray = np.zeros(size, dtype=bool)
        self.reinit: BoolArray = np.zeros(size, dtype=bool)
        # per-lamella normal and spline forces; None both when per_lamella is False
        self.normal: FloatArray | None = np.empty((size, self.lamellas)) if self.lamellas \
            else None
        self.spline: FloatArray | None = np.empty((size, self.lamellas)) if self.lamellas \
            else None

    def _grow(self, needed: int) -> None:
        """Reallocate for at least ``needed`` samples (doubling), keeping what was fed."""
        n = self.n
        ins, cols, accepted, reinit = self._in, self.cols, self.accepted, self.reinit
        normal, spline = self.normal, self.spline
        self._alloc(max(needed, 2 * cols.shape[1]))
        for k in _INPUTS:
            self._in[k][:n] = ins[k][:n]
        self.cols[:, :n], self.accepted[:n], self.reinit[:n] = (cols[:, :n], accepted[:n],
                                                                reinit[:n])
        if (self.normal is not None and self.spline is not None and normal is not None
                and spline is not None):  # (all four are arrays when self.lamellas)
            self.normal[:n], self.spline[:n] = normal[:n], spline[:n]

    def feed(self, t: ArrayLike, actuating_pressure: ArrayLike, lamella_temperature: ArrayLike,
             slip_speed: ArrayLike, measured_torque: ArrayLike = np.nan) -> None:
        """Estimate the next samples of the stream.

        Stamps [s] (1-D), pressure [Pa], temperature [°C] (NaN: not measured), slip [rad/s],
        measured torque [N m] (NaN: none); inputs broadcast to the stamps' shape.

        Raises:
            InputError: shapes do not broadcast.
            SampleRejected: (``on_reject="raise"``) the first rejected sample of this piece.

        """
        t = np.asarray(t, dtype=float)
        if t.ndim != 1:
            raise InputError(f"t must be 1-D, got shape {t.shape}")
        a, m = self.n, t.size
        b = a + m
        if b > self.cols.shape[1]:
            self._grow(b)
        try:
            vals = [np.broadcast_to(np.asarray(v, dtype=float), t.shape) for v in
                    (t, actuating_pressure, lamella_temperature, slip_speed, measured_torque)]
        except ValueError as err:
            raise InputError(f"inputs do not broadcast to t's shape {t.shape}: {err}") from err
        for key, v in zip(_INPUTS, vals):
            self._in[key][a:b] = v
        ins = {k: self._in[k][a:b] for k in _INPUTS}
        ok, kinds = self._rejections(ins)
        if self.on_reject == "raise" and not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            raise _REJECTED[int(kinds[i])](f"sample {a + i} rejected (stamp {t[i]!r})")
        self.accepted[a:b] = ok
        self.reinit[a:b] = False
        self.n = b
        if not ok.all():
            bad = a + np.flatnonzero(~ok)
            self.cols[:, bad] = np.nan
            if self.normal is not None and self.spline is not None:  # self.lamellas
                self.normal[bad] = np.nan
                self.spline[bad] = np.nan
        idx = a + np.flatnonzero(ok)
        if idx.size:
            self._estimate(idx)

    def _rejections(self, ins: dict[str, FloatArray]) -> tuple[BoolArray, IntArray]:
        """Return accepted flags and reject kinds (1 non-finite, 2 repeat, 3 older) of a piece."""
        t = ins["t"]
        finite = (np.isfinite(t) & np.isfinite(ins["p"]) & ~np.isinf(ins["temp"])
                  & np.isfinite(ins["omega"]) & ~np.isinf(ins["meas"]))
        # running[i]: the largest finite stamp before sample i (earlier pieces included)
        running = np.maximum.accumulate(
            np.concatenate([[self._prev_max], np.where(finite, t, -np.inf)]))
        prev, self._prev_max = running[:-1], float(running[-1])
        accepted = finite & (t > prev)
        kinds = np.where(~finite, 1, np.where(t == prev, 2, np.where(t < prev, 3, 0)))
        return accepted, kinds

    def _estimate(self, idx: IntArray) -> None:
        """Run the accepted rows ``idx`` (global, increasing) segment by segment."""
        t = self._in["t"]
        ta = t[idx]
        breaks = np.flatnonzero(np.diff(ta) > self.max_gap_s) + 1
        cont = self._last is not None and not ta[0] - t[self._last] > self.max_gap_s
        starts = np.concatenate([[0], breaks, [ta.size]])
        if self.model is None:
            self.model = PackModel(self.params)
        model = self.model
        for k, (s, e) in enumerate(zip(starts[:-1].tolist(), starts[1:].tolist())):
            rows = idx[s:e]
            if k == 0 and cont:
                self._segment(np.concatenate([[self._last], rows]), True, model)
            else:
                self.reinit[rows[0]] = True
                self._segment(rows, False, model)
        self._last = int(idx[-1])

    def _segment(self, rows: IntArray, cont: bool, model: PackModel) -> None:
        """Estimate the gap-free accepted ``rows`` into the output arrays.

        ``cont``: ``rows[0]`` is the previous piece's last accepted sample, already estimated;
        the filter and the pack continue from it (no reset) and its outputs are kept.
        """
        params, cols, nrm_all, spl_all = self.params, self.cols, self.normal, self.spline
        keep = (cols[:, rows[0]].copy(), None if nrm_all is None else nrm_all[rows[0]].copy(),
                None if spl_all is None else spl_all[rows[0]].copy()) if cont else None
        first, count = int(rows[0]), rows.size
        ins = self._in
        if int(rows[-1]) - first == count - 1:  # contiguous: views, written in place
            part = slice(first, first + count)
            ts, ps, temps, omegas = (ins[k][part] for k in ("t", "p", "temp", "omega"))
            out, nrm, spl, offset = cols, nrm_all, spl_all, first
        else:
            ts, ps, temps, omegas = (ins[k][rows] for k in ("t", "p", "temp", "omega"))
            out = np.empty((_N_COLS, count))
            nrm, spl = (None, None) if nrm_all is None else (
                np.empty((count, self.lamellas)), np.empty((count, self.lamellas)))
            offset = 0
        if keep is not None:  # cont: the filter continues from the last filtered value,
            omegas = omegas.copy()  # not from u[0]
            omegas[0] = keep[0][_SLIP]
        omega_f = kernel.lowpass_series(ts, omegas, params.slip.filter_time_constant,
                                        self.engine)
        out[_SLIP, offset:offset + count] = omega_f
        if not simulate_columns(params, ts, ps, omega_f, temps,
                                kernel.Columns(out, nrm, spl, offset), model=model,
                                engine=self.engine, reset=not cont):
            sim = simulate(params, ts, ps, omega_f, temps, model=model,
                           engine=self.engine, reset=not cont)
            dest = out[:, offset:offset + count]
            for i, name in enumerate(kernel.OUTPUT_COLUMNS[:-1]):
                dest[i] = getattr(sim, name)
            weights = np.arange(1, sim.spline_force.shape[1] + 1, dtype=float)
            dest[_CORRECTION] = sim.spline_force @ weights / (weights.size
                                                              * params.pack.piston_area)
            if nrm is not None and spl is not None:
                nrm[offset:offset + count] = sim.normal_force
                spl[offset:offset + count] = sim.spline_force
        self._comply(out, offset, count, ts, omegas, cont)
        if out is not cols:
            cols[:, rows] = out
            if nrm_all is not None and spl_all is not None and nrm is not None \
                    and spl is not None:
                nrm_all[rows] = nrm
                spl_all[rows] = spl
        if keep is not None:  # cont: sample rows[0] belongs to the previous piece: its
            cols[:, rows[0]] = keep[0]  # outputs stay as they were
            if nrm_all is not None and spl_all is not None and keep[1] is not None \
                    and keep[2] is not None:
                nrm_all[rows[0]], spl_all[rows[0]] = keep[1], keep[2]

    def _comply(self, out: FloatArray, offset: int, count: int, ts: FloatArray,
                omegas: FloatArray, cont: bool) -> None:
        """Apply the drivetrain compliance to a segment's outputs (torque, clutch slip)."""
        part = out[:, offset:offset + count]
        params = self.params
        if not params.drivetrain.enabled:
            part[_CLUTCH_SLIP] = np.nan
            return
        if not cont:
            reset_state(params, self._drive, float(part[_TORQUE, 0]), float(omegas[0]))
            part[_CLUTCH_SLIP, 0] = self._drive[1]
        t_kin, t_static = capacities(params, part[_MU], part[_Z], part[_TEMP])
        torque, slip = drive_series(params, np.diff(ts), omegas, t_kin, t_static,
                                    self._drive, self.engine)
        part[_TORQUE, 1:] = torque[1:]
        part[_CLUTCH_SLIP, 1:] = slip[1:]

    def result(self) -> EstimateBatch:
        """Return the :class:`EstimateBatch` of everything fed (views of this object's arrays)."""
        n = self.n
        ins = {k: v[:n] for k, v in self._in.items()}
        cols, accepted = self.cols[:, :n], self.accepted[:n]
        meas = ins["meas"]
        mod = cols[_TORQUE]
        with np.errstate(invalid="ignore", divide="ignore"):
            ok = accepted & ~np.isnan(meas) & (np.abs(mod) >= self.accuracy_min_torque)
            acc = np.where(ok, meas / np.where(ok, mod, 1.0), np.nan)
        with np.errstate(invalid="ignore"):
            over, under = acc > self.limits[0], acc < self.limits[1]
        every = bool(accepted.all())
        keep = np.copy if every else (lambda x: np.where(accepted, x, np.nan))
        normal, spline = self.normal, self.spline  # None both unless per_lamella
        return EstimateBatch(
            stamp=ins["t"].copy(), accepted=accepted, reinitialised=self.reinit[:n],
            modelled_torque=mod, reference_torque=cols[_REFERENCE], measured_torque=keep(meas),
            torque_accuracy=acc, friction_coefficient=cols[_MU],
            lamella_normal_force=None if normal is None else normal[:n],
            spline_friction_force=None if spline is None else spline[:n],
            front_pressure=cols[_FRONT], rear_pressure=cols[_REAR],
            pressure_difference=cols[_FRONT] - cols[_REAR], slip_speed_filtered=cols[_SLIP],
            overshoot=over, undershoot=under, actuating_pressure=keep(ins["p"]),
            lamella_temperature=cols[_TEMP], slip_speed=keep(ins["omega"]),
            compression=cols[_Z], spline_correction=cols[_CORRECTION],
            spline_law=self.params.spline.law, clutch_slip_speed=cols[_CLUTCH_SLIP])
