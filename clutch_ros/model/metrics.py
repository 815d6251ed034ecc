"""Validation metrics: torque accuracy, over/undershoot, RMSE, ±10 % band, Eq. 3, hysteresis.

Torques in N m, pressures in Pa. All functions take array-likes and ignore samples where an
input is NaN unless stated otherwise.

Torque accuracy (thesis 1.2): ``measured / modelled`` (model quality) or ``measured /
requested`` (control quality); NaN where the denominator's magnitude is below ``min_torque``
(the ratio is meaningless near zero torque). Overshoot: accuracy > 1.1; undershoot: < 0.9.

Cross-correlation (thesis Eq. 3, Ljung): ``R(τ) = 1/N Σ_t ε(t+τ) u(t)`` for lags −L…L, with
ε the residual (measured − modelled) and u an input. Both are de-meaned first (the normal
distribution with mean zero that Eq. 3 relies on needs zero-mean signals). If ε is white and
independent of u, R(τ) is approximately normal with standard deviation σ_ε σ_u / √N, so the
99 % confidence band is ±2.58 σ_ε σ_u / √N (z from the normal quantile of ``confidence``).
Values outside the band indicate input-dependent dynamics the model misses. (For coloured
residuals Ljung's band uses Σ_k R_ε(k) R_u(k) instead of σ_ε² σ_u²; this simpler band is what
the thesis applies.) The normalised correlation R/(σ_ε σ_u) and its band ±z/√N are also given.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.arraytypes import BoolArray, FloatArray, IntArray
from clutch_ros.model.errors import InputError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = [
    "torque_accuracy",
    "request_accuracy",
    "overshoot",
    "undershoot",
    "rmse",
    "within_band",
    "CrossCorrelation",
    "cross_correlation",
    "hysteresis_width",
    "accuracy_summary", "longest_run"]


def _ratio(num: ArrayLike, den: ArrayLike, min_torque: float) -> FloatArray:
    num = np.asarray(num, dtype=float)
    den = np.asarray(den, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.abs(den) >= min_torque
        return np.where(ok, num / np.where(ok, den, 1.0), np.nan)


def torque_accuracy(measured: ArrayLike, modelled: ArrayLike,
                    min_torque: float = 1.0) -> FloatArray:
    """Return measured / modelled; NaN where |modelled| < ``min_torque`` [N m] or NaN input."""
    return _ratio(measured, modelled, min_torque)


def request_accuracy(measured: ArrayLike, requested: ArrayLike,
                     min_torque: float = 1.0) -> FloatArray:
    """Return measured / requested; NaN where |requested| < ``min_torque`` [N m]."""
    return _ratio(measured, requested, min_torque)


def overshoot(accuracy: ArrayLike, limit: float = 1.1) -> BoolArray:
    """Return accuracy > ``limit`` (False for NaN)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(accuracy, dtype=float) > limit


def undershoot(accuracy: ArrayLike, limit: float = 0.9) -> BoolArray:
    """Return accuracy < ``limit`` (False for NaN)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(accuracy, dtype=float) < limit


def rmse(measured: ArrayLike, modelled: ArrayLike) -> float:
    """Root mean square of (measured − modelled) over finite pairs [N m]; NaN if none."""
    err = np.asarray(measured, dtype=float) - np.asarray(modelled, dtype=float)
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err * err))) if err.size else float("nan")


def within_band(measured: ArrayLike, modelled: ArrayLike, band: float = 0.1,
                threshold_fraction: float = 0.05,
                min_torque: float = 1.0) -> float:
    """Fraction of samples with accuracy in [1 − band, 1 + band].

    Only samples where |measured| ≥ ``threshold_fraction`` × max |measured| count (the
    accuracy is dominated by noise near zero torque). NaN if no sample counts.
    """
    return _band_summary(measured, {"model": modelled}, band, threshold_fraction,
                         min_torque)["model"][1]


@dataclass(frozen=True)
class CrossCorrelation:
    """Residual-input cross-correlation of Eq. 3 (module docstring).

    Attributes:
        lags: τ in samples, shape (2L + 1,)
        r: R(τ) in units of residual × input
        band: half width of the confidence band of r (same units)
        normalized: R(τ) / (σ_ε σ_u), in [-1, 1]
        band_normalized: z / √N
        outside: fraction of lags with |r| > band
        confidence: confidence level of the band (0.99)
        samples: N

    """

    lags: IntArray
    r: FloatArray
    band: float
    normalized: FloatArray
    band_normalized: float
    outside: float
    confidence: float
    samples: int


def cross_correlation(residual: ArrayLike, inputs: ArrayLike, max_lag: int = 50,
                      confidence: float = 0.99) -> CrossCorrelation:
    """Eq. 3 for lags −max_lag…max_lag with its confidence band (samples with NaN dropped)."""
    eps = np.asarray(residual, dtype=float)
    u = np.asarray(inputs, dtype=float)
    if eps.shape != u.shape or eps.ndim != 1:
        raise InputError(f"residual and input must be 1-D of equal length, got {eps.shape} "
                         f"and {u.shape}")
    keep = np.isfinite(eps) & np.isfinite(u)
    eps, u = eps[keep], u[keep]
    n = eps.size
    if n < 2 or not 0 <= max_lag < n:
        raise InputError(f"need at least 2 samples and 0 <= max_lag < N, got N={n}, "
                         f"max_lag={max_lag}")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must be in (0, 1), got {confidence!r}")
    eps = eps - eps.mean()
    u = u - u.mean()
    lags = np.arange(-max_lag, max_lag + 1)
    r = np.empty(lags.size)
    for i, lag in enumerate(lags.tolist()):
        if lag >= 0:
            r[i] = np.dot(eps[lag:], u[:n - lag]) / n
        else:
            r[i] = np.dot(eps[:n + lag], u[-lag:]) / n
    scale = float(eps.std() * u.std())
    # stdlib normal quantile (equal to scipy.stats.norm.ppf to ~1e-15); importing
    # scipy.stats costs ~0.8 s of every replay's start-up
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    band = z * scale / np.sqrt(n)
    normalized = r / scale if scale > 0.0 else np.zeros_like(r)
    outside = float(np.mean(np.abs(r) > band)) if scale > 0.0 else 0.0
    return CrossCorrelation(lags, r, float(band), normalized, z / float(np.sqrt(n)), outside,
                            float(confidence), int(n))


def hysteresis_width(pressure: ArrayLike, torque: ArrayLike, at_pressure: float) -> float:
    """Torque on the falling leg minus the rising leg at ``at_pressure`` [N m].

    The legs are split at the pressure maximum; each leg is interpolated at ``at_pressure``
    (the leg's pressure must be monotonic). Positive: more torque on the way down, the
    spline-friction hysteresis of Tables 5-6.
    """
    p = np.asarray(pressure, dtype=float)
    tq = np.asarray(torque, dtype=float)
    top = int(np.argmax(p))
    up_p, up_t = p[:top + 1], tq[:top + 1]
    dn_p, dn_t = p[top:][::-1], tq[top:][::-1]
    for leg in (up_p, dn_p):
        if np.any(np.diff(leg) < 0.0) or not leg[0] <= at_pressure <= leg[-1]:
            raise InputError(f"pressure legs must be monotonic and span {at_pressure!r} Pa")
    rise = np.interp(at_pressure, *_strict(up_p, up_t, last=True))
    fall = np.interp(at_pressure, *_strict(dn_p, dn_t, last=False))
    return float(fall - rise)


def _strict(p: FloatArray, t: FloatArray, last: bool) -> tuple[FloatArray, FloatArray]:
    """Keep one sample per plateau of equal pressure, the one latest in time (settled).

    ``last``: the array runs forward in time (keep the last of a run), else backward.
    """
    step = np.diff(p) > 0.0
    keep = np.append(step, True) if last else np.insert(step, 0, True)
    return p[keep], t[keep]


#: samples per block of :func:`accuracy_summary`'s reductions [1]: its temporaries stay small
#: (a few MB, reused by the allocator) however long the series
SUMMARY_BLOCK = 1 << 16


def accuracy_summary(measured: ArrayLike, modelled: ArrayLike, reference: ArrayLike | None = None,
                     threshold_fraction: float = 0.05, min_torque: float = 1.0,
                     where: ArrayLike | None = None) -> dict[str, float]:
    """Return the replay/demo numbers as a dict.

    Keys: samples, rmse_nm, reference_rmse_nm, within_10pct, reference_within_10pct,
    max_accuracy, min_accuracy (the accuracy extremes over the samples counted by
    :func:`within_band`); torques [N m], the rest [1]. ``where``: boolean mask of the samples
    to summarise (default: all), the same as passing ``measured[where]``, ... without their
    copies; ``samples`` counts them. The reference figures are NaN without ``reference``.

    Evaluated in blocks of :data:`SUMMARY_BLOCK` samples (:func:`_band_summary`, which
    :func:`within_band` uses too): a one-hour replay (3.6 M samples) had spent 0.3-0.7 s
    here, most of it faulting in the pages of whole-series temporaries. The sums of squares
    are added block by block, so the RMSE equals :func:`rmse` to rounding
    (tests/model/test_metrics.py: rtol 1e-12).
    """
    series = {"model": modelled} if reference is None else {"model": modelled,
                                                              "ref": reference}
    out = _band_summary(measured, series, 0.1, threshold_fraction, min_torque, where)
    nan = float("nan")
    rms, within, low, high, samples = out["model"]
    ref_rms, ref_within = out["ref"][:2] if "ref" in out else (nan, nan)
    return {"samples": samples, "rmse_nm": rms, "reference_rmse_nm": ref_rms,
            "within_10pct": within, "reference_within_10pct": ref_within,
            "max_accuracy": high, "min_accuracy": low}


def _band_summary(measured: ArrayLike, series: dict[str, ArrayLike], band: float,
                  threshold_fraction: float, min_torque: float,
                  where: ArrayLike | None = None,
                  ) -> dict[str, tuple[float, float, float, float, int]]:
    """Per model in ``series``: (RMSE, fraction within ±band, min and max accuracy, samples).

    The formulas of :func:`rmse`, :func:`within_band` and the accuracy extremes over the
    samples it counts, in blocks of :data:`SUMMARY_BLOCK` samples (see accuracy_summary).
    """
    meas = np.atleast_1d(np.asarray(measured, dtype=float))
    models = {k: np.broadcast_to(np.asarray(v, dtype=float), meas.shape)
              for k, v in series.items()}
    mask = None if where is None else np.broadcast_to(np.asarray(where, dtype=bool), meas.shape)
    blocks = [slice(a, a + SUMMARY_BLOCK) for a in range(0, meas.size, SUMMARY_BLOCK)]

    def usable(values: FloatArray, b: slice) -> BoolArray:
        ok = np.isfinite(values)
        return ok if mask is None else ok & mask[b]

    peak = 0.0  # pass 1: the threshold, from the largest |measured|
    for b in blocks:
        finite = usable(meas[b], b)
        if finite.any():
            peak = max(peak, float(np.max(np.abs(meas[b][finite]))))
    threshold = threshold_fraction * peak
    # per model: sum of squares, finite pairs, inside the band, lowest and highest accuracy
    sums: dict[str, list[float]] = {k: [0.0, 0, 0, np.inf, -np.inf] for k in models}
    counted_n = 0
    for b in blocks:  # pass 2: everything else
        m = meas[b]
        with np.errstate(invalid="ignore"):
            counted = usable(m, b) & (np.abs(m) >= threshold)
        counted_n += int(np.count_nonzero(counted))
        for key, values in models.items():
            err = m - values[b]
            e = err[usable(err, b)]
            acc = torque_accuracy(m, values[b], min_torque)
            with np.errstate(invalid="ignore"):
                inside = counted & (acc >= 1.0 - band) & (acc <= 1.0 + band)
            sel = acc[counted & np.isfinite(acc)]
            total = sums[key]
            total[0] += float(np.dot(e, e))
            total[1] += int(e.size)
            total[2] += int(np.count_nonzero(inside))
            if sel.size:
                total[3], total[4] = min(total[3], float(sel.min())), max(total[4],
                                                                          float(sel.max()))
    nan = float("nan")
    samples = int(meas.size if mask is None else np.count_nonzero(mask))
    return {k: (float(np.sqrt(sq / pairs)) if pairs else nan,
                inside / counted_n if counted_n else nan,
                low if np.isfinite(low) else nan, high if np.isfinite(high) else nan, samples)
            for k, (sq, pairs, inside, low, high) in sums.items()}


def longest_run(flags: ArrayLike, t: ArrayLike) -> float:
    """Longest contiguous stretch [s] where ``flags`` is True, on sorted times ``t`` [s].

    A stretch runs from its first True sample to the first False sample after it (or the
    last sample). Used for "no overshoot above 1.1 lasting longer than 0.5 s".
    """
    flags = np.asarray(flags, dtype=bool)
    t = np.asarray(t, dtype=float)
    longest, start = 0.0, None
    for flag, now in zip(flags.tolist(), t.tolist()):
        if flag and start is None:
            start = now
        elif not flag and start is not None:
            longest, start = max(longest, now - start), None
    if start is not None and t.size:
        longest = max(longest, float(t[-1]) - start)
    return float(longest)
