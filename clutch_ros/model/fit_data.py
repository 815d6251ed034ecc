"""The data side of the grey-box identification: runs in, fit-ready segments out, refusals.

Units: time [s], pressure [Pa], temperature [°C], slip speed [rad/s], torque [N m]. Used by
:func:`clutch_ros.model.identification.fit` (which re-exports the public names here); the fit
itself (parameterisation, residuals, solver, standard errors) lives there.

- Inputs: :class:`FitRun` (one measured run) and :class:`FitOptions` (tuning of the fit).
- Refusals (all :class:`IdentificationError`, a :class:`~clutch_ros.model.errors.ModelError`):
  no measured torque (:class:`NoMeasuredTorqueError`), too little data
  (:class:`TooShortError`), constant pressure (:class:`NoExcitationError`), a temperature span
  too small for the temperature slope or a rank-deficient Jacobian
  (:class:`UnidentifiableParameterError`, with ``keys``): :func:`check_data` before the fit,
  :func:`rank_check` on the solver's Jacobian after it.
- Preparation, for speed (a one-hour 1 kHz run fits in well under a minute, ``python -m
  benchmarks.model_fit``):

1. *Anti-aliased decimation.* Every run is cut at gaps longer than ``max_gap_s`` (as the
   estimator re-initialises there) and block-averaged to ``fit_rate_hz`` (default 100 Hz,
   never coarser than a tenth of the pack's slowest time constant, 0.125 s on the rig). The
   inputs are dt-weighted means over each block — exactly the zero-order-hold input the pack
   model integrates over the block (the model is an exact ZOH at any step) — and the measured
   outputs are block means (a boxcar anti-alias filter, noise / √M), compared with the same
   mean of the model output interpolated linearly over the block, so no half-block lag is
   introduced. Against the full-rate model the error is below 0.5 N m RMS on the Table 3 runs.
2. *Informative segments.* When the decimated data exceed ``max_samples`` (default
   :data:`SAMPLE_BUDGET`: 20 000 samples = 200 s at 100 Hz, 4 000 for coulomb), the runs
   are cut into episodes at rests (pressure below 3 % of its maximum for ≥ 1 s, where the
   pack is unloaded and the spline forces vanish, so a segment can start from the model's
   equilibrium), episodes longer than ``max_segment_s`` are chopped, and each keeps a
   ``warmup_s`` prefix that is simulated but not fitted. Episodes are then chosen round-robin
   over temperature strata (the temperature slope needs the whole temperature range), the
   most pressure-exciting episode of each stratum first (total variation of the pressure per
   simulated sample: excitation per unit of cost), until the budget is spent.

:func:`prepare_segments` does step 1 (rows the estimator would skip are dropped first: a
non-finite input or a stamp not later than the previous accepted one), :func:`select_segments`
step 2; :class:`Segment` is the decimated piece of a run the fit simulates.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.errors import (  # re-exported: defined in errors.py
    IdentificationError,
    NoExcitationError,
    NoMeasuredTorqueError,
    TooShortError,
    UnidentifiableParameterError,
)
from clutch_ros.model.laws import LawTable
from clutch_ros.model.params import ClutchParams
from clutch_ros.model.slip import lowpass_series
from clutch_ros.model.statespace import build_state_space

if TYPE_CHECKING:

    from clutch_ros.model.arraytypes import FloatArray, IntArray


__all__ = [
    "IdentificationError",
    "NoMeasuredTorqueError",
    "TooShortError",
    "NoExcitationError",
    "UnidentifiableParameterError",
    "FitRun",
    "FitOptions",
    "SAMPLE_BUDGET",
    "Segment",
    "prepare_segments",
    "select_segments",
    "model_block_means",
    "check_data",
    "rank_check",
]

#: Default segment budget per law [decimated samples per residual evaluation]: a coulomb
#: step (stick/slip active set) costs ~50 µs against ~3 µs for the others.
#: A live view of the registry's :attr:`~clutch_ros.model.laws.SplineLawInfo.sample_budget`.
SAMPLE_BUDGET = LawTable("sample_budget")


# -- inputs and options ---------------------------------------------------------------------
@dataclass(frozen=True)
class FitRun:
    """One measured run, arrays of shape (n,).

    Attributes:
        t: stamps [s] (strictly increasing; rows breaking that, or with a non-finite input,
            are skipped like the estimator skips them)
        pressure: actuating pressure [Pa]
        temperature: lamella temperature [°C]
        slip_speed: ω_diff [rad/s] (raw; filtered here as the estimator does)
        torque: measured torque [N m], NaN where absent
        pressure_difference: measured P_diff = front − rear lamella pressure [Pa], NaN
            where absent; None: not measured (then front − rear if both are given)
        front_pressure, rear_pressure: measured front/rear lamella pressures [Pa] (e.g.
            FlexiForce-derived); with both, the disc gains are fitted (module docstring)
        name: label for reports

    """

    t: np.ndarray
    pressure: np.ndarray
    temperature: np.ndarray
    slip_speed: np.ndarray
    torque: np.ndarray
    pressure_difference: np.ndarray | None = None
    name: str = ""
    front_pressure: np.ndarray | None = None
    rear_pressure: np.ndarray | None = None

    def __len__(self) -> int:
        return int(np.asarray(self.t).size)

    @property
    def has_discs(self) -> bool:
        """Both front and rear pressures are given."""
        return self.front_pressure is not None and self.rear_pressure is not None

    @property
    def measured_pdiff(self) -> np.ndarray | None:
        """P_diff [Pa]: ``pressure_difference``, else front − rear, else None."""
        if self.pressure_difference is not None:
            return np.asarray(self.pressure_difference, dtype=float)
        front, rear = self.front_pressure, self.rear_pressure
        if front is not None and rear is not None:  # self.has_discs
            diff: np.ndarray = np.asarray(front, dtype=float) - np.asarray(rear, dtype=float)
            return diff
        return None


@dataclass(frozen=True)
class FitOptions:
    """Tuning of :func:`fit` (defaults suit the thesis rig; units in brackets).

    Attributes:
        fit_rate_hz: decimated rate of the fit [Hz] (capped by the pack time constant / 10)
        max_samples: decimated samples simulated per residual evaluation (segment budget);
            None: :data:`SAMPLE_BUDGET` of the law; 0: every sample (no budget)
        max_segment_s: longest segment when segmenting [s]
        warmup_s: simulated-but-unfitted prefix of a segment [s]
        rest_fraction: a rest is pressure below this fraction of the run's maximum
        rest_s: minimum rest length for a cut [s]
        pdiff_weight: weight of the P_diff residual (in torque-equivalent units)
        pdiff_disc_gains: fit per-run front/rear disc gains when a run gives both pressures
        min_duration_s: least data with measured torque [s]
        min_samples_per_parameter: least decimated samples per fitted parameter
        min_pressure_span: least actuating pressure span [Pa] (2 bar)
        min_temperature_span: least lamella temperature span to fit the slope [°C]
        rank_tol: smallest singular value / largest of the normalised Jacobian
        max_gap_s: a larger gap between stamps splits a run (estimator's max_gap_s) [s]
        diff_step: finite-difference step in the scaled variables
        ftol, xtol, gtol, max_nfev: least-squares stopping rules (max_nfev: residual
            evaluations of the solver, Jacobian columns not counted)
        max_seconds: wall-time guard [s]: the solver stops after the iteration that would
            otherwise end past it (result ``converged`` False, best point so far); None: off
        min_slip_speed: samples with |ω| below this [rad/s] are simulated but not fitted: a
            locked clutch transmits what the drivetrain asks (up to its capacity), not what a
            friction law says, and a noisy slip sign there is noise, not information
        workers: threads that evaluate the finite-difference Jacobian's columns at once
            (each column is an independent simulation; the compiled kernel runs without the
            GIL); 1: one after the other. The columns, so the fit, are the same bits either
            way. How many cores a process may use is the caller's to know (``clutch fit``
            gives one per usable core)
        transition: how the fit's model computes ``e^{A dt}`` (PackModel ``transition``:
            ``"auto"``, closed form where it applies, or ``"expm"``); the fit's verdict and
            values do not depend on it (tests/offline/test_fit_robust.py)

    """

    fit_rate_hz: float = 100.0
    max_samples: int | None = None
    max_segment_s: float = 120.0
    warmup_s: float = 3.0
    rest_fraction: float = 0.03
    rest_s: float = 1.0
    pdiff_weight: float = 0.1
    pdiff_disc_gains: bool = True
    min_duration_s: float = 5.0
    min_samples_per_parameter: int = 20
    min_pressure_span: float = 2e5
    min_temperature_span: float = 2.0
    rank_tol: float = 1e-4
    max_gap_s: float = 1.0
    diff_step: float = 1e-3
    ftol: float = 1e-6
    xtol: float = 1e-6
    gtol: float = 1e-8
    max_nfev: int = 60
    max_seconds: float | None = None
    min_slip_speed: float = 0.05
    workers: int = 1
    transition: str = "auto"



# -- preprocessing --------------------------------------------------------------------------
@dataclass
class Segment:
    """A decimated piece of run ``run`` the fit simulates from equilibrium (arrays (n,))."""

    run: int
    t: np.ndarray
    p: np.ndarray
    omega: np.ndarray
    temp: np.ndarray
    torque: np.ndarray  # block means, NaN where unmeasured
    pdiff: np.ndarray | None
    discs: bool  # P_diff compared through fitted disc gains
    w: np.ndarray  # weight of the block's end sample in the block mean of the model
    fit: np.ndarray  # bool: residual samples (False in the warm-up)

    def __len__(self) -> int:
        return int(self.t.size)

    def part(self, a: int, b: int, warm: int) -> Segment:
        """Rows ``a:b`` as a segment whose first ``warm`` rows are not fitted."""
        fitmask = self.fit[a:b].copy()
        fitmask[:warm] = False
        w = self.w[a:b].copy()
        w[0] = 1.0
        return Segment(self.run, self.t[a:b], self.p[a:b], self.omega[a:b], self.temp[a:b],
                        self.torque[a:b], None if self.pdiff is None else self.pdiff[a:b],
                        self.discs, w, fitmask)


def _clean_run(run: FitRun, index: int, min_slip_speed: float = 0.0,
               ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                          FloatArray | None]:
    """Return the accepted rows (finite inputs, rising stamps) as arrays.

    The torque of rows with |ω| < ``min_slip_speed`` becomes NaN (not fitted).
    """
    t = np.asarray(run.t, dtype=float).ravel()
    n = t.size
    cols = []
    for name in ("pressure", "temperature", "slip_speed", "torque"):
        arr = np.asarray(getattr(run, name), dtype=float).ravel()
        if arr.size != n:
            raise IdentificationError(f"run {run.name or index}: {name} has {arr.size} "
                                      f"samples, t has {n}")
        cols.append(arr)
    pd = run.measured_pdiff
    if pd is not None:
        pd = pd.ravel()
        if pd.size != n:
            raise IdentificationError(f"run {run.name or index}: the P_diff measurement has "
                                      f"{pd.size} samples, t has {n}")
    p, temp, omega, torque = cols
    finite = np.isfinite(t) & np.isfinite(p) & np.isfinite(temp) & np.isfinite(omega)
    prev = np.maximum.accumulate(np.where(finite, t, -np.inf))
    prev = np.concatenate([[-np.inf], prev[:-1]])
    ok = finite & (t > prev)
    torque = np.where(np.isinf(torque) | (np.abs(omega) < min_slip_speed), np.nan, torque)
    return (t[ok], p[ok], temp[ok], omega[ok], torque[ok], None if pd is None else pd[ok])


def _block_means(t: FloatArray, x: FloatArray, ends: IntArray) -> FloatArray:
    """dt-weighted means of x over (t[e_{k-1}], t[e_k]]; x[0] for the first block."""
    dt = np.diff(t)
    c = np.concatenate([[0.0], np.cumsum(x[1:] * dt)])
    out = np.empty(ends.size)
    out[0] = x[0]
    out[1:] = (c[ends[1:]] - c[ends[:-1]]) / (t[ends[1:]] - t[ends[:-1]])
    return out


def _output_means(y: FloatArray, ends: IntArray) -> FloatArray:
    """NaN-aware plain means of y over samples (e_{k-1}, e_k]; NaN if under half valid."""
    ok = np.isfinite(y)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, y, 0.0))])
    k = np.concatenate([[0], np.cumsum(ok)])
    out = np.full(ends.size, np.nan)
    out[0] = y[0] if ok[0] else np.nan
    cnt = k[ends[1:] + 1] - k[ends[:-1] + 1]
    length = ends[1:] - ends[:-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (c[ends[1:] + 1] - c[ends[:-1] + 1]) / cnt
    out[1:] = np.where(2 * cnt >= length, mean, np.nan)
    return out


def _decimate(run_index: int, t: FloatArray, p: FloatArray, temp: FloatArray,
              omega_f: FloatArray, torque: FloatArray, pdiff: FloatArray | None, discs: bool,
              target_dt: float) -> Segment:
    n = t.size
    dt = float(np.median(np.diff(t))) if n > 1 else target_dt
    m = max(1, int(round(target_dt / dt))) if dt > 0.0 else 1
    ends = np.arange(0, n, m)
    if ends[-1] != n - 1:
        ends = np.append(ends, n - 1)
    length = np.diff(ends)
    w = np.ones(ends.size)
    w[1:] = (length + 1.0) / (2.0 * length)
    if n == 1:
        return Segment(run_index, t.copy(), p.copy(), omega_f.copy(), temp.copy(),
                        torque.copy(), None if pdiff is None else pdiff.copy(), discs, w,
                        np.isfinite(torque))
    tq = _output_means(torque, ends)
    pdm = None if pdiff is None else _output_means(pdiff, ends)
    return Segment(run_index, t[ends], _block_means(t, p, ends), _block_means(t, omega_f, ends),
                    _block_means(t, temp, ends), tq, pdm, discs, w, np.isfinite(tq))


def model_block_means(y: FloatArray, w: FloatArray) -> FloatArray:
    """Mean of the model output ``y`` over each block (linear within it; ``Segment.w``)."""
    out = y.copy()
    out[1:] = (1.0 - w[1:]) * y[:-1] + w[1:] * y[1:]
    return out


def _pack_time_constant(params: ClutchParams) -> float:
    pk = params.pack
    a, _ = build_state_space(pk.lamella_count, pk.lamella_mass, pk.lamella_stiffness,
                             pk.lamella_damping)
    slow = float(np.max(np.linalg.eigvals(a).real))
    return -1.0 / slow if slow < 0.0 else math.inf


def prepare_segments(runs: Iterable[FitRun], params: ClutchParams,
                     opts: FitOptions) -> list[Segment]:
    """Clean, cut at gaps, filter the slip speed and decimate every run (step 1)."""
    tau_slip = params.slip.filter_time_constant
    target_dt = 1.0 / opts.fit_rate_hz
    tau_pack = _pack_time_constant(params)
    if math.isfinite(tau_pack):
        target_dt = min(target_dt, tau_pack / 10.0)
    segments = []
    for i, run in enumerate(runs):
        t, p, temp, omega, torque, pdiff = _clean_run(run, i, opts.min_slip_speed)
        if t.size == 0:
            continue
        starts = np.concatenate([[0], np.flatnonzero(np.diff(t) > opts.max_gap_s) + 1,
                                 [t.size]])
        for a, b in zip(starts[:-1].tolist(), starts[1:].tolist()):
            omega_f = lowpass_series(t[a:b], omega[a:b], tau_slip)
            segments.append(_decimate(i, t[a:b], p[a:b], temp[a:b], omega_f, torque[a:b],
                                      None if pdiff is None else pdiff[a:b],
                                      run.has_discs and opts.pdiff_disc_gains, target_dt))
    return segments


def _episodes(seg: Segment, opts: FitOptions) -> list[Segment]:
    """Cut a segment at rests (module docstring); each piece keeps a warm-up prefix."""
    n = len(seg)
    if n < 3:
        return [seg]
    dt = float(np.median(np.diff(seg.t)))
    warm = max(1, int(round(opts.warmup_s / dt)))
    rest_len = max(1, int(round(opts.rest_s / dt)))
    longest = max(rest_len + 1, int(round(opts.max_segment_s / dt)))
    quiet = seg.p < opts.rest_fraction * max(float(np.max(np.abs(seg.p))), 1e-9)
    cuts = [0]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]])))
    for a, b in zip(edges[0::2].tolist(), edges[1::2].tolist()):
        if b - a >= rest_len and b < n:
            cuts.append(b - 1)  # the last quiet sample: the next episode starts unloaded
    cuts.append(n)
    bounds = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        while b - a > longest:
            bounds.append((a, a + longest))
            a += longest
        if b > a:
            bounds.append((a, b))
    out = []
    for a, b in bounds:
        start = max(0, a - warm)
        out.append(seg.part(start, b, a - start))
    return out


def select_segments(segments: list[Segment], opts: FitOptions, budget: int) -> list[Segment]:
    """Segments within the sample ``budget`` (module docstring, step 2)."""
    total = sum(len(s) for s in segments)
    if total <= budget:
        return segments
    pieces = [e for s in segments for e in _episodes(s, opts) if e.fit.any()]
    if not pieces:
        return segments[:1]
    pmax = max(float(np.max(np.abs(s.p))) for s in pieces) or 1.0
    # pressure total variation per simulated sample: excitation per unit of cost
    score = np.array([float(np.sum(np.abs(np.diff(s.p))[s.fit[1:]])) / pmax / len(s)
                      for s in pieces])
    temps = np.array([float(np.mean(s.temp[s.fit])) for s in pieces])
    sizes = np.array([len(s) for s in pieces])
    strata = int(np.clip(budget // max(int(np.median(sizes)), 1), 1, len(pieces)))
    rank = np.argsort(np.argsort(temps, kind="stable"), kind="stable")
    stratum = (rank * strata) // len(pieces)
    order = {k: sorted(np.flatnonzero(stratum == k).tolist(), key=lambda i: -score[i])
             for k in range(strata)}
    chosen: list[int] = []
    progress = True
    while progress:
        progress = False
        for k in range(strata):
            queue = order[k]
            while queue and sizes[queue[0]] > budget:
                queue.pop(0)
            if queue:
                i = queue.pop(0)
                chosen.append(i)
                budget -= int(sizes[i])
                progress = True
    if not chosen:
        chosen = [int(np.argmax(score))]
    return [pieces[i] for i in sorted(chosen)]


# -- refusals -------------------------------------------------------------------------------
def check_data(segments: Sequence[Segment], keys: Sequence[str], opts: FitOptions,
               runs: Sequence[FitRun]) -> None:
    """Raise the :class:`IdentificationError` the prepared ``segments`` deserve for ``keys``."""
    has = [s.fit & np.isfinite(s.torque) for s in segments]
    if not any(h.any() for h in has):
        raise NoMeasuredTorqueError(
            "no measured torque in any run (has_measured_torque false or NaN everywhere): "
            "there is nothing to fit the model to")
    duration = 0.0
    for s, h in zip(segments, has):
        if h.sum() > 1:
            duration += float(np.sum(np.diff(s.t)[h[1:]]))
    samples = int(sum(int(h.sum()) for h in has))
    need = opts.min_samples_per_parameter * len(keys)
    if duration < opts.min_duration_s or samples < need:
        raise TooShortError(
            f"too little data with measured torque: {duration:.2f} s, {samples} samples at the "
            f"fit rate; need at least {opts.min_duration_s:g} s and {need} samples for "
            f"{len(keys)} parameters")
    p = np.concatenate([s.p[h] for s, h in zip(segments, has)])
    span = float(np.ptp(p))
    # the film is excited by slip onsets under pressure, not by pressure changes
    static = ("friction.mu_ref", "friction.temperature_slope", "friction.film_depth",
              "friction.film_recovery_time", "friction.film_thinning_time")
    dyn = [k for k in keys if k not in static]
    if span < opts.min_pressure_span and dyn:
        raise NoExcitationError(
            f"the actuating pressure is constant (span {span / 1e5:.3f} bar < "
            f"{opts.min_pressure_span / 1e5:g} bar): {', '.join(dyn)} cannot be identified; "
            "record pressure steps or ramps (e.g. the incremented-step sequence)", dyn)
    if "friction.temperature_slope" in keys:
        temp = np.concatenate([s.temp[h] for s, h in zip(segments, has)])
        tspan = float(np.ptp(temp))
        if tspan < opts.min_temperature_span:
            raise UnidentifiableParameterError(
                f"friction.temperature_slope cannot be identified: the lamella temperature "
                f"spans only {tspan:.2f} °C (< {opts.min_temperature_span:g} °C); fix it "
                "(keep the base value) or add runs at other temperatures",
                ["friction.temperature_slope"])


def rank_check(jac: np.ndarray, keys: Sequence[str], tol: float) -> None:
    """Raise UnidentifiableParameterError when the normalised Jacobian loses rank (``tol``)."""
    norms = np.linalg.norm(jac, axis=0)
    top = float(norms.max()) if norms.size else 0.0
    dead = [k for k, nrm in zip(keys, norms) if not nrm > 1e-12 * max(top, 1e-300)]
    if dead or top == 0.0:
        dead = dead or list(keys)
        raise UnidentifiableParameterError(
            f"{', '.join(dead)} {'has' if len(dead) == 1 else 'have'} no effect on the modelled "
            "torque for these data; fix it or record data that excite it", dead)
    _, sv, vt = np.linalg.svd(jac / norms, full_matrices=False)
    if sv[-1] < tol * sv[0]:
        null = np.abs(vt[-1])
        names = [k for k, c in zip(keys, null) if c >= 0.3 * null.max()]
        raise UnidentifiableParameterError(
            f"rank-deficient Jacobian (singular value ratio {sv[-1] / sv[0]:.1e}): "
            f"{' and '.join(names)} cannot be told apart on these data; fix "
            f"{'one of them' if len(names) > 1 else 'it'} or add data that separate them",
            names)

