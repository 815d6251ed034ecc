"""Grey-box identification: fit the friction law, spline law and pack damping to rig data.

Units: time [s], pressure [Pa], temperature [°C], slip speed [rad/s], torque [N m]. The model
is the estimator's own (:func:`~clutch_ros.model.simulate.simulate` on the slip speed filtered
like :func:`~clutch_ros.model.batch.estimate_batch` does), so fitted parameters deploy to
the live nodes unchanged.

What is fitted (:data:`FREE_PARAMETERS`, dotted keys; ``fixed=`` removes any of them):

- always the friction law: ``friction.mu_ref``, ``friction.temperature_slope``,
  ``friction.pressure_loss_at_ref``, and the pack damping ``clutch.lamella_damping`` (it sets
  the torque time constant; thesis 6.4.2 fits it "coherently with the spline friction");
- ``ff_t``/``ff_v``: ``spline.gain`` (κ) and ``spline.time_constant`` (τ);
- ``coulomb``: ``spline.friction_coefficient`` (μ_s; only μ_s / r_s matters, r_s is kept).

Objective: nonlinear least squares (:func:`scipy.optimize.least_squares`, trust-region
reflective, bounds) of the residuals of :class:`~clutch_ros.model.fit_problem.FitProblem`:
measured − modelled torque [N m] over all runs, plus the weighted P_diff residual where a run
carries a P_diff measurement; the problem's module docstring gives the residuals (P_diff
disc gains by variable projection), the parameterisation and the bounds. Start: the base
parameters (Table 7 for ff_t/ff_v when the base has another law), with μ_ref rescaled by a
linear least-squares fit of Eq. 1 to the torque.

Standard errors: ``σ² (JᵀJ)⁻¹`` with ``σ² = Σ r² / (m − n)`` and J the solver's
finite-difference Jacobian at the optimum, mapped to parameter units (``v · se`` for log
parameters). They assume white residuals and exact inputs; noisy inputs (temperature,
pressure) and model error make them optimistic — on the simulated rig the true error is 1–5
standard errors: read them as a lower bound. The same Jacobian, with its columns normalised,
must have full rank: a singular value below ``rank_tol`` of the largest raises
:class:`UnidentifiableParameterError` naming the parameters of the null direction.

The Jacobian (solver and rank check): central differences where both one-sided differences
agree, else the one-sided slope of smaller magnitude (:mod:`~clutch_ros.model.fd_jacobian`).
The residuals jump where a parameter moves a stick-slip event of the drivetrain compliance
across a sample stamp, and a fit's optimum tends to sit right at such an edge; forward
differences across it spiked the columns that crossed, so that the rank check's verdict
depended on round-off (the coulomb fit with ``--fit-compliance`` flipped on a 1e-9 change of
the discretisation).

Refusals and data preparation (decimation, :data:`SAMPLE_BUDGET`): :mod:`~.fit_data`.
Speed (``python -m benchmarks.model_fit``): an evaluation simulates ``max_samples`` samples
(0: all) in the kernel's output-only loop (``simulate_columns``, ~0.5 µs each); 5–15
iterations of 2 n + 1 evaluations; ``max_seconds`` (45 s) ends a fit early, not converged.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model.batch import estimate_batch
from clutch_ros.model.fd_jacobian import JacobianOf
from clutch_ros.model.fit_data import (
    SAMPLE_BUDGET,
    FitOptions,
    FitRun,
    IdentificationError,
    NoExcitationError,
    NoMeasuredTorqueError,
    TooShortError,
    UnidentifiableParameterError,
    check_data,
    prepare_segments,
    rank_check,
    select_segments,
)
from clutch_ros.model.fit_problem import TRANSFORM, FitProblem
from clutch_ros.model.friction import reference_torque
from clutch_ros.model.laws import LawTable, law_info
from clutch_ros.model.metrics import rmse
from clutch_ros.model.params import PARAMETER_SPECS, SPLINE_LAWS, TABLE7, ClutchParams

if TYPE_CHECKING:
    from clutch_ros.model.fit_data import Segment

__all__ = [
    # errors and inputs (defined in clutch_ros.model.fit_data)
    "IdentificationError", "NoMeasuredTorqueError", "TooShortError", "NoExcitationError",
    "UnidentifiableParameterError", "FitRun", "FitOptions", "SAMPLE_BUDGET",
    # the fit and the validation replay
    "FitResult", "RunEvaluation", "FREE_PARAMETERS", "fit", "evaluate", "initial_params",
]

#: Parameters fitted per spline law (dotted keys), before ``fixed``: a live view of the
#: registry's :attr:`~clutch_ros.model.laws.SplineLawInfo.free_parameters`.
FREE_PARAMETERS = LawTable("free_parameters")


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
    pdiff_gains: dict[str, tuple[float, float]]
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

    def to_dict(self) -> dict[str, Any]:
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
        return law_info(law).gain_unit or PARAMETER_SPECS[key].unit
    return PARAMETER_SPECS[key].unit


# -- the fit --------------------------------------------------------------------------------
def initial_params(base: ClutchParams, law: str) -> ClutchParams:
    """Return ``base`` switched to ``law`` with usable start values for the fit.

    ff_t/ff_v take Table 7 (10 rpm) when the base has another law or a zero gain; coulomb
    keeps a positive ``spline.friction_coefficient`` (0.05 if 0); a zero damping becomes the
    one giving a 0.1 s torque time constant (c = 0.1 s · k).
    """
    if law not in SPLINE_LAWS:
        raise IdentificationError(f"unknown spline law {law!r} (one of {', '.join(SPLINE_LAWS)})")
    info = law_info(law)
    params = base
    if info.table7 is not None:
        if base.spline.law != law or not base.spline.gain > 0.0:
            entry = TABLE7[(info.table7, 10)]
            params = params.replace(**{"spline.law": law, "spline.gain": entry.gain_si,
                                       "spline.time_constant": entry.time_constant})
    else:
        params = params.replace(**{"spline.law": law})
    changes = {}
    flat = params.to_flat()
    for key, value in info.start:  # coulomb: a positive spline.friction_coefficient
        if not flat[key] > 0.0:
            changes[key] = value
    if not params.pack.lamella_damping > 0.0:
        changes["clutch.lamella_damping"] = 0.1 * params.pack.lamella_stiffness
    return params.updated(changes) if changes else params


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
    unknown = [k for k in list(keys) + list(fixed) if k not in TRANSFORM]
    if unknown:
        raise IdentificationError(f"cannot fit {', '.join(unknown)} (fittable: "
                                  f"{', '.join(TRANSFORM)})", unknown)
    keys = [k for k in keys if k not in set(fixed)]
    if not keys:
        raise IdentificationError("every parameter is fixed: nothing to fit")
    workers = _workers(opts.workers, len(keys))
    segments = prepare_segments(runs, params0, opts)
    check_data(segments, keys, opts, runs)
    fit_dt = float(np.median(np.concatenate([np.diff(s.t) for s in segments if len(s) > 1])))
    budget = opts.max_samples if opts.max_samples is not None else SAMPLE_BUDGET[law]
    if budget:  # 0: every sample
        segments = select_segments(segments, opts, int(budget))
    if "friction.mu_ref" in keys:
        params0 = _scale_mu(params0, segments)
    problem = FitProblem(params0, keys, segments, opts)
    z0 = np.clip(np.zeros(len(keys)), problem.lower, problem.upper)
    # scipy.optimize takes ~0.7 s to import; loaded by a fit, not by everything that imports
    # this module (replay reports use RunEvaluation)
    from scipy.optimize import least_squares

    # the Jacobian: both one-sided differences per column, so that a residual jumping within a
    # step of the point (a break-away crossing a sample stamp) cannot spike it (fd_jacobian);
    # its 2 n evaluations run in `workers` threads (the same bits either way)
    pool = ThreadPoolExecutor(workers, thread_name_prefix="clutch-fit") if workers > 1 else None
    try:
        fun = JacobianOf(problem, opts.diff_step, pool.map if pool else map)
        res = least_squares(fun, z0, jac=fun.jacobian, bounds=(problem.lower, problem.upper),
                            method="trf", x_scale=1.0, ftol=opts.ftol, xtol=opts.xtol,
                            gtol=opts.gtol, max_nfev=opts.max_nfev,
                            callback=_Deadline(t0, opts.max_seconds))
        z = res.x
        jac = res.jac  # the jump-robust Jacobian at res.x (central where the sides agree)
    finally:  # an interrupt does not wait for the columns still queued
        if pool:
            pool.shutdown(wait=True, cancel_futures=True)
    rank_check(jac, keys, opts.rank_tol)
    params = problem.params(z)
    values = problem.values(z)
    torque_res, pdiff_res = problem.residuals_parts(params, problem.gains)
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


def _workers(asked: int, columns: int) -> int:
    """Threads for the Jacobian: ``asked``, at most one per column."""
    if not isinstance(asked, int) or asked < 1:
        raise IdentificationError(f"FitOptions.workers must be an integer >= 1, got {asked!r}")
    return min(asked, columns)


class _Deadline:
    """least_squares callback: stop when the next iteration would end after the deadline."""

    def __init__(self, start: float, seconds: float | None) -> None:
        self.start = start
        self.seconds = seconds
        self.last = time.perf_counter()

    def __call__(self, intermediate_result: object) -> None:
        now = time.perf_counter()
        step, self.last = now - self.last, now
        if self.seconds is not None and now - self.start + step > self.seconds:
            raise StopIteration


def _scale_mu(params: ClutchParams, segments: Iterable[Segment]) -> ClutchParams:
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
    extra: dict[str, Any] = field(default_factory=dict)


def evaluate(params: ClutchParams, run: FitRun) -> RunEvaluation:
    """Replay ``run`` through :func:`estimate_batch` (bad rows skipped) and score it."""
    batch = estimate_batch(params, run.t, run.pressure, run.temperature, run.slip_speed,
                           run.torque, on_reject="skip")
    ok = batch.accepted
    meas = batch.measured_torque
    spline = batch.spline_friction_force
    assert spline is not None  # per_lamella, the default
    return RunEvaluation(
        name=run.name, law=params.spline.law, rmse=rmse(meas[ok], batch.modelled_torque[ok]),
        reference_rmse=rmse(meas[ok], batch.reference_torque[ok]),
        t=np.asarray(run.t, dtype=float)[ok], measured=meas[ok],
        modelled=batch.modelled_torque[ok], reference=batch.reference_torque[ok],
        pressure=batch.actuating_pressure[ok],
        pressure_difference=batch.pressure_difference[ok],
        spline_force=spline[ok],
        measured_pdiff=None if run.measured_pdiff is None else run.measured_pdiff[ok])
