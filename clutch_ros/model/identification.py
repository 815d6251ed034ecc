"""Grey-box identification: fit the friction law, spline law and pack damping to rig data.

Units: time [s], pressure [Pa], temperature [°C], slip speed [rad/s], torque [N m]. The model
is the estimator's own (:func:`~clutch_ros.model.simulate.simulate` on the slip speed filtered
like :func:`~clutch_ros.model.estimator.estimate_batch` does), so fitted parameters deploy to
the live nodes unchanged.

What is fitted (:data:`FREE_PARAMETERS`, dotted keys; ``fixed=`` removes any of them):

- always the friction law: ``friction.mu_ref``, ``friction.temperature_slope``,
  ``friction.pressure_loss_at_ref``, and the pack damping ``clutch.lamella_damping`` (it sets
  the torque time constant; thesis 6.4.2 fits it "coherently with the spline friction");
- ``ff_t``/``ff_v``: ``spline.gain`` (κ) and ``spline.time_constant`` (τ);
- ``coulomb``: ``spline.friction_coefficient`` (μ_s; only μ_s / r_s matters, r_s is kept).

Objective: nonlinear least squares (:func:`scipy.optimize.least_squares`, trust-region
reflective, bounds) of the residual measured − modelled torque [N m] over all runs, plus, where
a run carries a P_diff measurement (FlexiForce-derived, :mod:`~clutch_ros.model.calibration`),
``pdiff_weight · g · (P_diff,measured − P_diff,model)`` with ``g = 2 μ_ref R_e N A`` [N m/Pa]
(the torque one pascal of actuating pressure gives), so both terms are in N m.

A FlexiForce calibration fitted against the actuating force (thesis §5.5) assumes that the
rear disc carries the same force as the front one, so each disc's estimate is off by an
unknown gain (the average spline loss, sensor drift) and a raw P_diff carries a bias of the
order of 1 bar that would pull the friction law away from the torque. When a run gives the
front and rear pressures separately, the model P_diff is therefore compared as
``c_f · P_front,model − c_r · P_rear,model`` with per-run disc gains ``(c_f, c_r)`` solved by
linear least squares inside every residual evaluation (variable projection;
``pdiff_disc_gains``): P_diff informs the *dynamics* of the spline loss (its sign changes
between compression and rebound), not its absolute level — what the thesis trusts it for.

Parameterisation: positive parameters (μ_ref, κ, τ, μ_s, c) are fitted as ``log(v / v0)``,
the signed ones as ``(v − v0) / scale`` (1e-3 1/°C for the temperature slope, 0.01 for the
pressure loss), so every variable is O(1) and one finite-difference step (1e-3) suits all.
Bounds: the ranges of :data:`~clutch_ros.model.params.PARAMETER_SPECS`, the cross-key rules of
:class:`~clutch_ros.model.params.ClutchParams` (μ_ref ≥ μ_min, a pressure loss that keeps the
torque rising up to ``max_pressure``) and three decades either side of the start for the log
parameters. Start: the base parameters (Table 7 for ff_t/ff_v when the base has another law),
with μ_ref rescaled by a linear least-squares fit of Eq. 1 to the torque.

Standard errors: ``σ² (JᵀJ)⁻¹`` with ``σ² = Σ r² / (m − n)`` and J the solver's
finite-difference Jacobian at the optimum (central differences when it is near-singular),
mapped to parameter units (``v · se`` for log parameters). They assume white residuals and
exact inputs; noisy inputs (temperature, pressure) and model error make them optimistic — on
the simulated rig the true error is 1–5 standard errors: read them as a lower bound. The
same Jacobian, with its columns normalised, must have full rank: a singular value below
``rank_tol`` of the largest raises :class:`UnidentifiableParameterError` naming the
parameters of the null direction.

Refusals (all :class:`IdentificationError`, a :class:`~clutch_ros.model.errors.ModelError`):
no measured torque (:class:`NoMeasuredTorqueError`), too little data
(:class:`TooShortError`), constant pressure (:class:`NoExcitationError`), a temperature span
too small for the temperature slope or a rank-deficient Jacobian
(:class:`UnidentifiableParameterError`, with ``keys``).

Speed (a one-hour 1 kHz run fits in well under a minute, ``python -m
clutch_ros.model.fit_bench``):

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

Each residual evaluation then simulates at most ``max_samples`` samples (≈ 0.06 s; with the
coulomb law 0.2–1 s, its stick/slip steps cost 50–250 µs each, most while plates slide); a
fit takes 5–15 least-squares iterations of n + 1 evaluations (forward differences; the final
Jacobian is re-done with central differences only when it looks near-singular). A wall-time
guard (``max_seconds``, 45 s) ends a fit that would still run longer with its best point,
flagged not converged.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from clutch_ros.model.errors import ModelError
from clutch_ros.model.estimator import estimate_batch
from clutch_ros.model.friction import reference_torque
from clutch_ros.model.metrics import rmse
from clutch_ros.model.pack import PackModel
from clutch_ros.model.params import PARAMETER_SPECS, SPLINE_LAWS, TABLE7, ClutchParams
from clutch_ros.model.simulate import simulate
from clutch_ros.model.slip import lowpass_series
from clutch_ros.model.statespace import build_state_space

__all__ = [
    "IdentificationError",
    "NoMeasuredTorqueError",
    "TooShortError",
    "NoExcitationError",
    "UnidentifiableParameterError",
    "FitRun",
    "FitOptions",
    "FitResult",
    "RunEvaluation",
    "FREE_PARAMETERS",
    "SAMPLE_BUDGET",
    "fit",
    "evaluate",
    "initial_params",
]

#: Parameters fitted per spline law (dotted keys), before ``fixed``.
FREE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "none": ("friction.mu_ref", "friction.temperature_slope", "friction.pressure_loss_at_ref",
             "clutch.lamella_damping"),
    "ff_t": ("friction.mu_ref", "friction.temperature_slope", "friction.pressure_loss_at_ref",
             "spline.gain", "spline.time_constant", "clutch.lamella_damping"),
    "ff_v": ("friction.mu_ref", "friction.temperature_slope", "friction.pressure_loss_at_ref",
             "spline.gain", "spline.time_constant", "clutch.lamella_damping"),
    "coulomb": ("friction.mu_ref", "friction.temperature_slope",
                "friction.pressure_loss_at_ref", "spline.friction_coefficient",
                "clutch.lamella_damping"),
}

#: key -> (log parameterisation, linear scale)
_TRANSFORM = {
    "friction.mu_ref": (True, 1.0),
    "friction.temperature_slope": (False, 1e-3),
    "friction.pressure_loss_at_ref": (False, 0.01),
    "spline.gain": (True, 1.0),
    "spline.time_constant": (True, 1.0),
    "spline.friction_coefficient": (True, 1.0),
    "clutch.lamella_damping": (True, 1.0),
}
_LOG_SPAN = math.log(1e3)  # log parameters may move three decades either way
#: Default segment budget per law [decimated samples per residual evaluation]: a coulomb
#: step (stick/slip active set) costs ~50 µs against ~3 µs for the others.
SAMPLE_BUDGET = {"none": 20_000, "ff_t": 20_000, "ff_v": 15_000, "coulomb": 4_000}


# -- errors ---------------------------------------------------------------------------------
class IdentificationError(ModelError):
    """The data cannot identify the model (the message says why and what to change).

    ``keys``: the dotted parameter keys concerned (may be empty).
    """

    def __init__(self, message: str, keys: Sequence[str] = ()):
        super().__init__(message)
        self.keys = tuple(keys)


class NoMeasuredTorqueError(IdentificationError):
    """No run carries a measured torque to fit against."""


class TooShortError(IdentificationError):
    """Too little data with a measured torque (duration or samples per parameter)."""


class NoExcitationError(IdentificationError):
    """The actuating pressure (the model's input) hardly varies."""


class UnidentifiableParameterError(IdentificationError):
    """A parameter (``keys``) has no effect or is confounded with others on these data."""


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
        if self.has_discs:
            return (np.asarray(self.front_pressure, dtype=float)
                    - np.asarray(self.rear_pressure, dtype=float))
        return None


@dataclass(frozen=True)
class FitOptions:
    """Tuning of :func:`fit` (defaults suit the thesis rig; units in brackets).

    Attributes:
        fit_rate_hz: decimated rate of the fit [Hz] (capped by the pack time constant / 10)
        max_samples: decimated samples simulated per residual evaluation (segment budget);
            None: :data:`SAMPLE_BUDGET` of the law (coulomb steps cost ~20x the others)
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
    max_seconds: float | None = 45.0


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes:
        params: the complete fitted :class:`ClutchParams` (base + fitted values)
        law: spline law fitted
        keys: fitted dotted keys, in order
        values: fitted value per key (parameter units, see PARAMETER_SPECS)
        stderr: standard error per key (same units)
        initial: start value per key
        correlation: (n, n) correlation matrix of the estimates
        rmse: torque RMSE over all fitted samples [N m] (decimated grid)
        pdiff_rmse: P_diff RMSE [Pa] (NaN without P_diff data)
        pdiff_gains: per run name, the fitted disc gains (c_f, c_r) (runs with both)
        run_rmse: torque RMSE per run [N m] (NaN for a run without fitted samples)
        run_names: run labels
        iterations: least-squares iterations (Jacobian evaluations)
        evaluations: residual evaluations including the finite differences
        samples: fitted samples (torque); segments: simulated segments
        fit_rate_hz: rate of the fitted grid [Hz]
        seconds: wall time of the fit [s]
        converged: the solver met a tolerance; message: its message

    """

    params: ClutchParams
    law: str
    keys: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    initial: dict[str, float]
    correlation: np.ndarray
    rmse: float
    pdiff_rmse: float
    pdiff_gains: dict
    run_rmse: tuple[float, ...]
    run_names: tuple[str, ...]
    iterations: int
    evaluations: int
    samples: int
    segments: int
    fit_rate_hz: float
    seconds: float
    converged: bool
    message: str

    def to_dict(self) -> dict:
        """JSON-friendly summary: law, values, stderr, rmse, per-run RMSE, solver figures."""
        return {
            "law": self.law, "values": dict(self.values), "stderr": dict(self.stderr),
            "initial": dict(self.initial), "rmse": self.rmse, "pdiff_rmse": self.pdiff_rmse,
            "pdiff_gains": {k: list(v) for k, v in self.pdiff_gains.items()},
            "run_rmse": {name: value for name, value in zip(self.run_names, self.run_rmse)},
            "iterations": self.iterations, "evaluations": self.evaluations,
            "samples": self.samples, "segments": self.segments,
            "fit_rate_hz": self.fit_rate_hz, "seconds": self.seconds,
            "converged": self.converged, "message": self.message,
        }

    def lines(self) -> list[str]:
        """Human-readable lines: one per fitted value (± standard error, unit), then RMSE."""
        out = []
        for key in self.keys:
            unit = _unit(key, self.law)
            out.append(f"{key:32s} = {self.values[key]:.6g} ± {self.stderr[key]:.2g}"
                       + (f" [{unit}]" if unit else ""))
        out.append(f"fit RMSE {self.rmse:.3f} N m over {self.samples} samples at "
                   f"{self.fit_rate_hz:g} Hz ({self.segments} segments, {self.iterations} "
                   f"iterations, {self.seconds:.1f} s)")
        if math.isfinite(self.pdiff_rmse):
            out.append(f"P_diff RMSE {self.pdiff_rmse / 1e5:.3f} bar")
        return out


def _unit(key: str, law: str) -> str:
    if key == "spline.gain":
        return "1/m" if law == "ff_t" else "s/m^2"
    return PARAMETER_SPECS[key].unit


# -- preprocessing --------------------------------------------------------------------------
@dataclass
class _Segment:
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

    def part(self, a: int, b: int, warm: int) -> _Segment:
        fitmask = self.fit[a:b].copy()
        fitmask[:warm] = False
        w = self.w[a:b].copy()
        w[0] = 1.0
        return _Segment(self.run, self.t[a:b], self.p[a:b], self.omega[a:b], self.temp[a:b],
                        self.torque[a:b], None if self.pdiff is None else self.pdiff[a:b],
                        self.discs, w, fitmask)


def _clean_run(run: FitRun, index: int):
    """Return the accepted rows (finite inputs, rising stamps) as arrays."""
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
    torque = np.where(np.isinf(torque), np.nan, torque)
    return (t[ok], p[ok], temp[ok], omega[ok], torque[ok], None if pd is None else pd[ok])


def _block_means(t, x, ends):
    """dt-weighted means of x over (t[e_{k-1}], t[e_k]]; x[0] for the first block."""
    dt = np.diff(t)
    c = np.concatenate([[0.0], np.cumsum(x[1:] * dt)])
    out = np.empty(ends.size)
    out[0] = x[0]
    out[1:] = (c[ends[1:]] - c[ends[:-1]]) / (t[ends[1:]] - t[ends[:-1]])
    return out


def _output_means(y, ends):
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


def _decimate(run_index, t, p, temp, omega_f, torque, pdiff, discs, target_dt) -> _Segment:
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
        return _Segment(run_index, t.copy(), p.copy(), omega_f.copy(), temp.copy(),
                        torque.copy(), None if pdiff is None else pdiff.copy(), discs, w,
                        np.isfinite(torque))
    tq = _output_means(torque, ends)
    pdm = None if pdiff is None else _output_means(pdiff, ends)
    return _Segment(run_index, t[ends], _block_means(t, p, ends), _block_means(t, omega_f, ends),
                    _block_means(t, temp, ends), tq, pdm, discs, w, np.isfinite(tq))


def _pack_time_constant(params: ClutchParams) -> float:
    pk = params.pack
    a, _ = build_state_space(pk.lamella_count, pk.lamella_mass, pk.lamella_stiffness,
                             pk.lamella_damping)
    slow = float(np.max(np.linalg.eigvals(a).real))
    return -1.0 / slow if slow < 0.0 else math.inf


def _prepare(runs, params, opts: FitOptions) -> list[_Segment]:
    tau_slip = params.slip.filter_time_constant
    target_dt = 1.0 / opts.fit_rate_hz
    tau_pack = _pack_time_constant(params)
    if math.isfinite(tau_pack):
        target_dt = min(target_dt, tau_pack / 10.0)
    segments = []
    for i, run in enumerate(runs):
        t, p, temp, omega, torque, pdiff = _clean_run(run, i)
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


def _episodes(seg: _Segment, opts: FitOptions) -> list[_Segment]:
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


def _select(segments: list[_Segment], opts: FitOptions, budget: int) -> list[_Segment]:
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


# -- the fit --------------------------------------------------------------------------------
def initial_params(base: ClutchParams, law: str) -> ClutchParams:
    """Return ``base`` switched to ``law`` with usable start values for the fit.

    ff_t/ff_v take Table 7 (10 rpm) when the base has another law or a zero gain; coulomb
    keeps a positive ``spline.friction_coefficient`` (0.05 if 0); a zero damping becomes the
    one giving a 0.1 s torque time constant (c = 0.1 s · k).
    """
    if law not in SPLINE_LAWS:
        raise IdentificationError(f"unknown spline law {law!r} (one of {', '.join(SPLINE_LAWS)})")
    params = base
    if law in ("ff_t", "ff_v"):
        if base.spline.law != law or not base.spline.gain > 0.0:
            entry = TABLE7[(law, 10)]
            params = params.replace(**{"spline.law": law, "spline.gain": entry.gain_si,
                                       "spline.time_constant": entry.time_constant})
    else:
        params = params.replace(**{"spline.law": law})
    changes = {}
    if law == "coulomb" and not params.spline.friction_coefficient > 0.0:
        changes["spline.friction_coefficient"] = 0.05
    if not params.pack.lamella_damping > 0.0:
        changes["clutch.lamella_damping"] = 0.1 * params.pack.lamella_stiffness
    return params.updated(changes) if changes else params


class _Problem:
    """Residuals of the scaled parameter vector z over the selected segments."""

    def __init__(self, base: ClutchParams, keys, segments, opts: FitOptions):
        self.base = base
        self.keys = tuple(keys)
        self.segments = segments
        self.opts = opts
        flat = base.to_flat()
        self.v0 = np.array([float(flat[k]) for k in self.keys])
        self.log = np.array([_TRANSFORM[k][0] for k in self.keys])
        self.scale = np.array([_TRANSFORM[k][1] for k in self.keys])
        self.lower, self.upper = self._bounds()
        pk = base.pack
        self.torque_per_pa = (2.0 * base.friction.mu_ref * pk.effective_radius
                              * pk.lamella_count * pk.piston_area)
        self.calls = 0
        self.gains: dict[int, tuple[float, float]] = {}
        self.n_torque = int(sum(int((s.fit & np.isfinite(s.torque)).sum()) for s in segments))
        self.n_pdiff = int(sum(int((s.fit & np.isfinite(s.pdiff)).sum()) for s in segments
                               if s.pdiff is not None)) if opts.pdiff_weight > 0.0 else 0

    def _bounds(self):
        lo, hi = [], []
        fr, pk = self.base.friction, self.base.pack
        for key, v0, log, scale in zip(self.keys, self.v0, self.log, self.scale):
            spec = PARAMETER_SPECS[key]
            vmin = spec.minimum if spec.minimum is not None else -math.inf
            vmax = spec.maximum if spec.maximum is not None else math.inf
            if key == "friction.mu_ref":
                vmin = max(vmin, fr.mu_min)
            if key == "friction.pressure_loss_at_ref":
                vmax = min(vmax, 0.999 * fr.pressure_ref / (2.0 * pk.max_pressure))
            if key == "spline.time_constant":
                vmin, vmax = max(vmin, 1e-3), min(vmax, 1e3)
            if log:
                a = math.log(max(vmin, v0 * 1e-12, 1e-300) / v0) if vmin > 0 else -_LOG_SPAN
                b = math.log(vmax / v0) if math.isfinite(vmax) else _LOG_SPAN
                lo.append(max(a, -_LOG_SPAN) + 1e-9)
                hi.append(min(b, _LOG_SPAN) - 1e-9)
            else:
                lo.append((vmin - v0) / scale + 1e-9)
                hi.append((vmax - v0) / scale - 1e-9)
        return np.array(lo), np.array(hi)

    def values(self, z) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        return np.where(self.log, self.v0 * np.exp(np.where(self.log, z, 0.0)),
                        self.v0 + self.scale * z)

    def params(self, z) -> ClutchParams:
        vals = self.values(z)
        return self.base.updated({k: float(v) for k, v in zip(self.keys, vals)})

    def simulate(self, params):
        """Block-mean model outputs (torque, front and rear pressure) per segment."""
        model = PackModel(params)
        out = []
        for s in self.segments:
            sim = simulate(params, s.t, s.p, s.omega, s.temp, model=model)
            out.append((_blend(sim.torque, s.w), _blend(sim.front_pressure, s.w),
                        _blend(sim.rear_pressure, s.w)))
        return out

    def residuals_parts(self, params):
        """Torque residuals [N m] and P_diff residuals [Pa], one array per segment."""
        torque_res, pdiff_res = [], []
        rows: dict[int, list] = {}
        for i, (s, (tq, front, rear)) in enumerate(zip(self.segments, self.simulate(params))):
            ok = s.fit & np.isfinite(s.torque)
            torque_res.append(s.torque[ok] - tq[ok])
            pdiff_res.append(np.zeros(0))
            if s.pdiff is not None and self.n_pdiff:
                okp = s.fit & np.isfinite(s.pdiff)
                if s.discs:
                    rows.setdefault(s.run, []).append((i, s.pdiff[okp], front[okp], rear[okp]))
                else:
                    pdiff_res[i] = s.pdiff[okp] - (front[okp] - rear[okp])
        for run, parts in rows.items():
            meas = np.concatenate([p[1] for p in parts])
            design = np.column_stack([np.concatenate([p[2] for p in parts]),
                                      -np.concatenate([p[3] for p in parts])])
            gains = np.ones(2)
            if meas.size >= 2 and np.linalg.matrix_rank(design) == 2:
                gains = np.linalg.lstsq(design, meas, rcond=None)[0]
            self.gains[run] = (float(gains[0]), float(gains[1]))
            for i, pd, front, rear in parts:
                pdiff_res[i] = pd - (gains[0] * front - gains[1] * rear)
        return torque_res, pdiff_res

    def __call__(self, z) -> np.ndarray:
        self.calls += 1
        torque_res, pdiff_res = self.residuals_parts(self.params(z))
        parts = torque_res + [r * (self.opts.pdiff_weight * self.torque_per_pa)
                              for r in pdiff_res]
        return np.concatenate(parts)


def _blend(y, w):
    """Mean of the model output over each block (linear within the block)."""
    out = y.copy()
    out[1:] = (1.0 - w[1:]) * y[:-1] + w[1:] * y[1:]
    return out


def _check_data(segments, keys, opts: FitOptions, runs) -> None:
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
    if span < opts.min_pressure_span:
        dyn = [k for k in keys if k != "friction.mu_ref" and k != "friction.temperature_slope"]
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


def _central_jacobian(problem: _Problem, z, step: float) -> np.ndarray:
    cols = []
    for i in range(z.size):
        h = np.zeros_like(z)
        h[i] = step
        lo = max(z[i] - step, problem.lower[i])
        hi = min(z[i] + step, problem.upper[i])
        zp, zm = z.copy(), z.copy()
        zp[i], zm[i] = hi, lo
        cols.append((problem(zp) - problem(zm)) / (hi - lo))
    return np.column_stack(cols)


def _conditioning(jac: np.ndarray) -> float:
    """Smallest / largest singular value of the column-normalised Jacobian (0 if a column is 0)."""
    norms = np.linalg.norm(jac, axis=0)
    if not (norms > 0.0).all():
        return 0.0
    sv = np.linalg.svd(jac / norms, compute_uv=False)
    return float(sv[-1] / sv[0])


def _rank_check(jac: np.ndarray, keys, tol: float) -> None:
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


def fit(runs: Sequence[FitRun], law: str, base: ClutchParams, *,
        fixed: Sequence[str] = (), free: Sequence[str] | None = None,
        options: FitOptions | None = None,
        start: Mapping[str, float] | None = None) -> FitResult:
    """Fit ``law``'s parameters (module docstring) to ``runs``; return a :class:`FitResult`.

    Args:
        runs: measured runs (:class:`FitRun`).
        law: ``none``, ``ff_t``, ``ff_v`` or ``coulomb``.
        base: parameters providing everything not fitted and the start values.
        fixed: keys to keep at their base value.
        free: keys to fit instead of :data:`FREE_PARAMETERS` [law].
        options: :class:`FitOptions`.
        start: start values overriding the base for some keys.

    Raises:
        IdentificationError: (subclasses) the data cannot identify the parameters.

    """
    t0 = time.perf_counter()
    opts = options or FitOptions()
    if not runs:
        raise IdentificationError("no runs to fit")
    params0 = initial_params(base, law)
    if start:
        params0 = params0.updated(dict(start))
    keys = list(free if free is not None else FREE_PARAMETERS[law])
    unknown = [k for k in list(keys) + list(fixed) if k not in _TRANSFORM]
    if unknown:
        raise IdentificationError(f"cannot fit {', '.join(unknown)} (fittable: "
                                  f"{', '.join(_TRANSFORM)})", unknown)
    keys = [k for k in keys if k not in set(fixed)]
    if not keys:
        raise IdentificationError("every parameter is fixed: nothing to fit")
    segments = _prepare(runs, params0, opts)
    _check_data(segments, keys, opts, runs)
    fit_dt = float(np.median(np.concatenate([np.diff(s.t) for s in segments if len(s) > 1])))
    budget = opts.max_samples if opts.max_samples is not None else SAMPLE_BUDGET[law]
    segments = _select(segments, opts, int(budget))
    if "friction.mu_ref" in keys:
        params0 = _scale_mu(params0, segments)
    problem = _Problem(params0, keys, segments, opts)
    z0 = np.clip(np.zeros(len(keys)), problem.lower, problem.upper)
    res = least_squares(problem, z0, bounds=(problem.lower, problem.upper), method="trf",
                        x_scale=1.0, diff_step=opts.diff_step, ftol=opts.ftol, xtol=opts.xtol,
                        gtol=opts.gtol, max_nfev=opts.max_nfev,
                        callback=_Deadline(t0, opts.max_seconds))
    z = res.x
    jac = res.jac
    if _conditioning(jac) < 1e-2:  # near-singular: confirm with O(h²) central differences
        jac = _central_jacobian(problem, z, opts.diff_step)
    _rank_check(jac, keys, opts.rank_tol)
    params = problem.params(z)
    values = problem.values(z)
    torque_res, pdiff_res = problem.residuals_parts(params)
    r = np.concatenate(torque_res + [x * (opts.pdiff_weight * problem.torque_per_pa)
                                     for x in pdiff_res])
    m, n = r.size, len(keys)
    sigma2 = float(r @ r) / max(m - n, 1)
    cov_z = sigma2 * np.linalg.pinv(jac.T @ jac)
    deriv = np.where(problem.log, values, problem.scale)
    se = np.sqrt(np.maximum(np.diag(cov_z), 0.0)) * np.abs(deriv)
    d = np.sqrt(np.maximum(np.diag(cov_z), 1e-300))
    corr = cov_z / np.outer(d, d)
    all_t = np.concatenate(torque_res)
    all_p = np.concatenate(pdiff_res) if pdiff_res else np.zeros(0)
    per_run = []
    for i in range(len(runs)):
        rr = [x for s, x in zip(segments, torque_res) if s.run == i]
        cat = np.concatenate(rr) if rr else np.zeros(0)
        per_run.append(float(np.sqrt(np.mean(cat * cat))) if cat.size else math.nan)
    return FitResult(
        params=params, law=law, keys=tuple(keys),
        values={k: float(v) for k, v in zip(keys, values)},
        stderr={k: float(s) for k, s in zip(keys, se)},
        initial={k: float(v) for k, v in zip(keys, problem.v0)},
        correlation=corr, rmse=float(np.sqrt(np.mean(all_t * all_t))),
        pdiff_rmse=float(np.sqrt(np.mean(all_p * all_p))) if all_p.size else math.nan,
        pdiff_gains={(runs[i].name or f"run{i}"): g for i, g in sorted(problem.gains.items())},
        run_rmse=tuple(per_run), run_names=tuple(r.name or f"run{i}" for i, r in enumerate(runs)),
        iterations=int(res.njev or 0), evaluations=problem.calls, samples=problem.n_torque,
        segments=len(segments), fit_rate_hz=1.0 / fit_dt, seconds=time.perf_counter() - t0,
        converged=bool(res.status > 0),
        message=(f"stopped at the {opts.max_seconds:g} s time limit (max_seconds) before "
                 "converging" if res.status == -2 else str(res.message)))


class _Deadline:
    """least_squares callback: stop when the next iteration would end after the deadline."""

    def __init__(self, start: float, seconds: float | None):
        self.start = start
        self.seconds = seconds
        self.last = time.perf_counter()

    def __call__(self, intermediate_result) -> None:
        now = time.perf_counter()
        step, self.last = now - self.last, now
        if self.seconds is not None and now - self.start + step > self.seconds:
            raise StopIteration


def _scale_mu(params: ClutchParams, segments) -> ClutchParams:
    """Rescale μ_ref so Eq. 1 matches the measured torque in the least-squares sense."""
    num = den = 0.0
    for s in segments:
        ok = s.fit & np.isfinite(s.torque)
        ref = np.asarray(reference_torque(params, s.p[ok], s.temp[ok], s.omega[ok]))
        num += float(ref @ s.torque[ok])
        den += float(ref @ ref)
    if not (den > 0.0 and num > 0.0):
        return params
    fr = params.friction
    mu = float(np.clip(fr.mu_ref * num / den, max(fr.mu_min, 1e-3) * 1.001, 0.999))
    return params.replace(**{"friction.mu_ref": mu})


# -- validation -----------------------------------------------------------------------------
@dataclass(frozen=True)
class RunEvaluation:
    """A run replayed through the estimator at its full rate (validation, thesis 6.5).

    ``rmse``: model vs measured torque [N m]; ``reference_rmse``: Eq. 1 with the same
    friction law vs measured [N m]; arrays (n,): ``t`` [s], ``measured``, ``modelled``,
    ``reference`` [N m], ``pressure_difference`` (modelled) [Pa], ``spline_force`` (n, N)
    [N], ``measured_pdiff`` [Pa] or None, ``pressure`` [Pa]; ``law``; ``name``.
    """

    name: str
    law: str
    rmse: float
    reference_rmse: float
    t: np.ndarray
    measured: np.ndarray
    modelled: np.ndarray
    reference: np.ndarray
    pressure: np.ndarray
    pressure_difference: np.ndarray
    spline_force: np.ndarray
    measured_pdiff: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def evaluate(params: ClutchParams, run: FitRun) -> RunEvaluation:
    """Replay ``run`` through :func:`estimate_batch` (bad rows skipped) and score it."""
    batch = estimate_batch(params, run.t, run.pressure, run.temperature, run.slip_speed,
                           run.torque, on_reject="skip")
    ok = batch.accepted
    meas = batch.measured_torque
    return RunEvaluation(
        name=run.name, law=params.spline.law, rmse=rmse(meas[ok], batch.modelled_torque[ok]),
        reference_rmse=rmse(meas[ok], batch.reference_torque[ok]),
        t=np.asarray(run.t, dtype=float)[ok], measured=meas[ok],
        modelled=batch.modelled_torque[ok], reference=batch.reference_torque[ok],
        pressure=batch.actuating_pressure[ok],
        pressure_difference=batch.pressure_difference[ok],
        spline_force=batch.spline_friction_force[ok],
        measured_pdiff=None if run.measured_pdiff is None else run.measured_pdiff[ok])
