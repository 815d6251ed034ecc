"""Torque uncertainty: the 1-sigma prediction error of ``modelled_torque`` [N m].

An error model on the estimator's own outputs (it uses residuals only, so it is re-identified
after any change of the model). Per sample, causally (the node computes it sample by sample,
the replay with the same loop, :func:`torque_std`):

* ``T`` = ``|modelled_torque|`` [N m];
* ``R`` = ``|dT/dt|`` low-pass filtered with ``time_constant`` [N m/s] (first order, the
  backward difference of the modelled torque; a gap above ``max_gap`` restarts it at 0);
* ``S`` = 1 while the clutch sticks (``|slip_speed_filtered| < stick_speed``), else 0;
* ``L`` = ``R / |slip_speed_filtered|`` [N m / rad] while the clutch slips (``|slip| >=
  slip_floor``), else 0: the rate over the slip speed. Through the drivetrain's compliance
  the torque builds up in proportion to the slip speed (the thesis's Test A: a 3-4 s delay
  at the lowest slip speed), so the time by which the model can be off in a transient grows
  as the slip speed falls: ``rate_time * R`` is an error of a fixed time (any transient, the
  stuck clutch's too), ``rate_slip * L`` one of a fixed twist angle ``rate_slip`` [rad].

The independent parts add in quadrature (variances add; a sum of standard deviations would
count the sensor's noise again in every term)::

    sigma = sqrt(noise^2 + base^2 + (rel * T)^2 + (rate_time * R)^2 + (stick_rel * S * T)^2
                 + (rate_slip * L)^2)

:func:`fit_error_model` identifies them on a fitting run in two steps. ``noise`` [N m], the
torque sensor's own noise, comes first and apart from the model terms: the residual's robust
std over the samples where the model says the clutch carries nothing (``|modelled|`` at most
``QUIET_FRACTION`` of the run's largest: a residual there is the sensor's noise, whatever the
model). ``base`` [N m], ``rel`` [1], ``rate_time`` [s], ``stick_rel`` [1] and ``rate_slip``
[rad] are then the Gaussian maximum-likelihood fit of the residuals (``sum(log sigma + r^2 /
(2 sigma^2))``, minimised over the logarithms of the five, so each stays >= 0, from several
starts: it has local minima; a term whose feature the run lacks goes to 0) with ``noise``
fixed. Last, one quantile calibration scales the model terms (not the sensor's noise) so that 95 %
of the fitting run's ``|residual| / sigma`` are below 1.96. The parameters live in the
parameter file under ``uncertainty.*`` (:data:`DEFAULTS` when absent).

With a torque sensor the node knows how wrong the model has just been, and the model's error is
mostly an offset held for seconds (a friction hysteresis after a pressure change, the same
across noise seeds). With ``M`` the low-pass (``recent_mean_time_constant`` [s]) of the residual
and ``E`` the low-pass (``recent_time_constant`` [s]) of the squared standardised innovation
``((r - g M) / sigma)^2`` over the *previous* measured samples (:mod:`.recent_error`; ``M`` 0
and ``E`` 1 before the first and after a gap above ``max_gap``; held while no measurement
comes), ``g`` = ``recent_mean_weight``, the next residual is predicted as ``N(g M, v)``::

    v = noise^2 + recent_scale^2 * (1 - recent_weight + recent_weight * E) * (sigma^2 - noise^2)

(the sensor's noise is white: the recent error scales the model terms only) and
``modelled_torque_std`` is ``sqrt(v)`` at ``g M = 0``, else the std of the zero-mean normal
with the same central 95 % interval (:func:`.recent_error.central_half_width` / 1.96): a held,
well-fitted offset gets a band just beyond it, not 1.96 times it. Without a sensor ``E`` stays
1 and ``M`` 0. ``recent_mean_weight`` and ``recent_weight`` [1] (0..1) are the Gaussian ML fit
of ``N(g M, v)`` under the calibrated ``sigma``, ``recent_scale`` [1] a second calibration to
95 % within the band (when ``base.recent_time_constant > 0``; ``g`` = 0 when
``base.recent_mean_time_constant`` is 0). The time constants are not fitted: 0.05 s and 0.5 s
were chosen by leave-one-fitting-run-out cross-validation
(:func:`clutch_ros.offline.band.cross_validate_band`; benchmarks/RESULTS.md).

Phases (for :func:`coverage`): a sample is *transient* within ``TRANSIENT_WINDOW`` [s] after
the actuating pressure moved faster than ``TRANSIENT_RATE`` of its run's range per second
(``|dp/dt|``, backward difference over ``RATE_SPAN`` [s]), or the slip speed reversed (its
sign outside ``+-SLIP_DEADBAND`` [rad/s] changed); every other sample is *steady*. A slow
ramp is steady throughout (a run may have no transient sample: its fraction is then NaN).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from clutch_ros.model.errors import ModelError
from clutch_ros.model.recent_error import (
    RecentResidual,
    central_half_width,
    fit_recent,
    recent_series,
    smallest_scale,
)

__all__ = [
    "DEFAULTS", "QUIET_FRACTION", "ErrorModel", "TRANSIENT_RATE", "TRANSIENT_WINDOW",
    "RATE_SPAN", "SLIP_DEADBAND", "Z95", "coverage", "features", "fit_error_model",
    "negative_log_likelihood", "phases", "sensor_noise", "torque_std",
]

#: Two-sided 95 % quantile of the normal distribution.
Z95 = 1.959963984540054
#: Phase definition: pressure rate [1/s of the run's pressure range] marking a transient.
TRANSIENT_RATE = 0.2
#: Phase definition: the pressure rate is the difference over this span [s] (not the noise).
RATE_SPAN = 0.1
#: Phase definition: how long a sample stays transient after the marker [s].
TRANSIENT_WINDOW = 1.0
#: Phase definition: slip speeds within +- this are no direction (noise at standstill) [rad/s].
SLIP_DEADBAND = 0.3
#: Parameter file namespace of the error model.
NAMESPACE = "uncertainty"
#: Median of a chi-squared variable of one degree of freedom.
CHI2_1_MEDIAN = 0.454936423119572
#: Sensor-noise samples: ``|modelled|`` at most this fraction of the run's largest [1].
QUIET_FRACTION = 0.01


@dataclass(frozen=True)
class ErrorModel:
    """Parameters of the torque error model (module docstring), SI units.

    Attributes:
        noise: the torque sensor's noise, 1 sigma [N m], >= 0.
        base: constant part of the model's error [N m], >= 0.
        rel: part proportional to ``|modelled_torque|`` [1], >= 0.
        rate_time: part proportional to the filtered ``|dT/dt|`` [s], >= 0.
        stick_rel: extra part proportional to the torque while the clutch sticks [1], >= 0.
        rate_slip: part proportional to the filtered ``|dT/dt|`` over the slip speed
            (``L``, module docstring) [rad], >= 0.
        time_constant: low-pass time constant of the torque rate [s], > 0.
        stick_speed: slip speed below which the clutch counts as sticking [rad/s], > 0.
        max_gap: a time step above it (or not positive) restarts the rate filter [s], > 0.
        slip_floor: ``L`` is 0 below this slip speed (not slipping) [rad/s], > 0.
        recent_weight: weight of the recent error in the band (module docstring) [1], 0..1.
        recent_time_constant: low-pass time constant of the recent error [s], >= 0 (0:
            :func:`fit_error_model` leaves the recent error out).
        recent_scale: factor of the model terms (the second calibration) [1], > 0.
        recent_mean_weight: weight ``g`` of the recent offset ``M`` in the band
            (:mod:`clutch_ros.model.recent_error`) [1], 0..1 (0: the band of ``E`` alone).
        recent_mean_time_constant: low-pass time constant of ``M`` [s], >= 0 (0:
            :func:`fit_error_model` leaves ``M`` out, ``recent_mean_weight`` 0).

    """

    noise: float = 0.0
    base: float = 5.0
    rel: float = 0.1
    rate_time: float = 0.05
    stick_rel: float = 0.0
    time_constant: float = 0.1
    stick_speed: float = 0.1
    max_gap: float = 0.5
    rate_slip: float = 0.0
    slip_floor: float = 0.5
    recent_weight: float = 0.0
    recent_time_constant: float = 0.5
    recent_scale: float = 1.0
    recent_mean_weight: float = 0.0
    recent_mean_time_constant: float = 0.05

    def __post_init__(self) -> None:
        for name in ("recent_weight", "recent_mean_weight"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and value > 1.0:
                raise ModelError(f"{NAMESPACE}.{name} must be in [0, 1], got {value!r}")
        for name, value in asdict(self).items():
            positive = name in ("time_constant", "stick_speed", "max_gap", "slip_floor",
                                "recent_scale")
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and (value > 0 if positive else value >= 0)):
                need = "> 0" if positive else ">= 0"
                raise ModelError(f"{NAMESPACE}.{name} must be a finite number {need}, "
                                 f"got {value!r}")

    def to_flat(self) -> dict[str, float]:
        """Return ``{"uncertainty.<name>": value}`` for a parameter file."""
        return {f"{NAMESPACE}.{k}": float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_flat(cls, flat: Mapping[str, Any]) -> ErrorModel:
        """Build from dotted keys (others ignored; missing ones take the defaults).

        Raises:
            ModelError: an unknown ``uncertainty.*`` key or a bad value.

        """
        known = set(asdict(cls()))
        values: dict[str, float] = {}
        for key, value in flat.items():
            if not str(key).startswith(NAMESPACE + "."):
                continue
            name = str(key).split(".", 1)[1]
            if name not in known:
                raise ModelError(f"unknown parameter {key!r} (known: "
                                 f"{', '.join(sorted(known))})")
            values[name] = value
        return cls(**values)


#: The error model when the parameter file has none.
DEFAULTS = ErrorModel()


def features(model: ErrorModel, t: np.ndarray, modelled: np.ndarray,
             slip: np.ndarray) -> np.ndarray:
    """Return the (n, 4) features ``T``, ``R``, ``S``, ``L`` (module docstring) of every sample.

    ``t`` [s], ``modelled`` [N m], ``slip`` = ``slip_speed_filtered`` [rad/s]. Non-finite
    torques give NaN rows and leave the filter as it was.
    """
    t = np.asarray(t, dtype=float)
    modelled = np.asarray(modelled, dtype=float)
    slip = np.asarray(slip, dtype=float)
    out = np.full((t.size, 4), np.nan)
    state = _RateFilter(model)
    for i in range(t.size):
        rate = state.update(float(t[i]), float(modelled[i]))
        if not math.isnan(rate):
            speed = abs(float(slip[i]))
            out[i] = (abs(modelled[i]), rate, float(speed < model.stick_speed),
                      _lag(model, rate, speed))
    return out


class _RateFilter:
    """The causal low-pass filtered ``|dT/dt|`` [N m/s] (one place for node and replay)."""

    def __init__(self, model: ErrorModel):
        self.model = model
        self.t = math.nan
        self.torque = math.nan
        self.rate = 0.0

    def update(self, t: float, torque: float) -> float:
        """Feed one sample; return the filtered rate (NaN for a non-finite torque)."""
        if not math.isfinite(torque):
            return math.nan
        dt = t - self.t
        if math.isfinite(dt) and 0.0 < dt <= self.model.max_gap:
            raw = abs(torque - self.torque) / dt
            self.rate += dt / (self.model.time_constant + dt) * (raw - self.rate)
        else:
            self.rate = 0.0
        self.t, self.torque = t, torque
        return self.rate


def _lag(model: ErrorModel, rate: float, speed: float) -> float:
    """Return ``L`` [N m/rad] of a filtered rate [N m/s] at a slip speed [rad/s] >= 0."""
    return rate / speed if speed >= model.slip_floor else 0.0


def _sigma(model: ErrorModel, torque: float, rate: float, stick: float, lag: float) -> float:
    return math.sqrt(model.noise ** 2 + model.base ** 2 + (model.rel * torque) ** 2
                     + (model.rate_time * rate) ** 2 + (model.stick_rel * stick * torque) ** 2
                     + (model.rate_slip * lag) ** 2)


class TorqueStd:
    """Per-sample ``modelled_torque_std`` [N m] for the live node (same as :func:`torque_std`)."""

    def __init__(self, model: ErrorModel = DEFAULTS):
        """Start with an empty filter."""
        self.model = model
        self._filter = _RateFilter(model)
        self.predictive = (0.0, math.nan)
        self._recent = RecentResidual(model.recent_time_constant,
                                      model.recent_mean_time_constant,
                                      model.recent_mean_weight, model.max_gap)

    def update(self, t: float, modelled: float, slip: float,
               measured: float = math.nan) -> float:
        """Return the std of one estimate (``t`` [s], torques [N m], slip [rad/s]).

        ``measured`` (NaN: none) counts for the recent error of the *next* samples only.
        """
        sigma = self.static(t, modelled, slip)
        if math.isnan(sigma):
            return math.nan
        m = self.model
        gain = m.recent_scale ** 2 * (1.0 - m.recent_weight + m.recent_weight * self._recent.at(t))
        std = math.sqrt(m.noise ** 2 + gain * max(sigma * sigma - m.noise ** 2, 0.0))
        offset = m.recent_mean_weight * self._recent.mean_at(t)
        self.predictive = (offset, std)  # the residual predicted as N(offset, std^2)
        if offset != 0.0:  # the zero-mean normal with the same central 95 % interval
            std = central_half_width(offset, std) / Z95
        self._recent.update(t, measured - modelled, sigma)
        return std

    def static(self, t: float, modelled: float, slip: float) -> float:
        """Feed one sample; return ``sigma`` (the terms in quadrature, no recent error)."""
        rate = self._filter.update(t, modelled)
        if math.isnan(rate):
            return math.nan
        speed = abs(slip)
        stick = 1.0 if speed < self.model.stick_speed else 0.0
        return _sigma(self.model, abs(modelled), rate, stick, _lag(self.model, rate, speed))


def torque_std(model: ErrorModel, t: np.ndarray, modelled: np.ndarray,
               slip: np.ndarray, measured: np.ndarray | None = None) -> np.ndarray:
    """Return ``modelled_torque_std`` [N m] of every sample, exactly as :class:`TorqueStd`.

    ``measured`` [N m] (NaN where absent; None: no torque sensor) feeds the recent error.
    """
    est = TorqueStd(model)
    meas = np.full(len(t), np.nan) if measured is None else np.asarray(measured, dtype=float)
    return np.array([est.update(float(a), float(b), float(c), float(d))
                     for a, b, c, d in zip(t, modelled, slip, meas)], dtype=float)


def fit_error_model(t: np.ndarray, modelled: np.ndarray, measured: np.ndarray,
                    slip: np.ndarray, base: ErrorModel = DEFAULTS) -> ErrorModel:
    """Identify the error model on one run (module docstring); filter settings from ``base``.

    Raises:
        ModelError: fewer than 20 samples with both a measurement and a finite estimate.

    """
    x = features(base, t, modelled, slip)
    resid = np.asarray(measured, dtype=float) - np.asarray(modelled, dtype=float)
    ok = np.isfinite(resid) & np.all(np.isfinite(x), axis=1)
    if ok.sum() < 20:
        raise ModelError(f"the error model needs at least 20 measured samples, got {ok.sum()}")
    x, resid = x[ok], resid[ok]
    noise = sensor_noise(x[:, 0], resid)
    # columns: the model terms' features (base, rel, rate_time, stick_rel, rate_slip)
    design = np.column_stack([np.ones(len(x)), x[:, 0], x[:, 1], x[:, 2] * x[:, 0], x[:, 3]])
    coef = _max_likelihood(design, resid, noise)
    terms = (design * coef) ** 2 @ np.ones(design.shape[1])
    ratio = np.abs(resid) / Z95
    k = _calibration(ratio, noise ** 2, terms)
    coef = coef * k
    model = replace(base, noise=noise, base=float(coef[0]), rel=float(coef[1]),
                    rate_time=float(coef[2]), stick_rel=float(coef[3]),
                    rate_slip=float(coef[4]), recent_weight=0.0, recent_scale=1.0,
                    recent_mean_weight=0.0)
    if base.recent_time_constant > 0.0:
        model = _fit_recent(model, t, modelled, measured, slip)
    return model


def _fit_recent(model: ErrorModel, t: np.ndarray, modelled: np.ndarray, measured: np.ndarray,
                slip: np.ndarray) -> ErrorModel:
    """Fit ``recent_mean_weight``, ``recent_weight`` (ML) and ``recent_scale`` (95 %)."""
    est = TorqueStd(model)
    sigma = np.array([est.static(float(a), float(b), float(c))
                      for a, b, c in zip(t, modelled, slip)], dtype=float)
    resid = np.asarray(measured, dtype=float) - np.asarray(modelled, dtype=float)
    if model.recent_mean_time_constant > 0.0:
        g, w, scale = fit_recent(np.asarray(t, dtype=float), resid, sigma, model.noise,
                                 model.recent_time_constant, model.recent_mean_time_constant,
                                 model.max_gap)
        return replace(model, recent_mean_weight=g, recent_weight=w, recent_scale=scale)
    from scipy.optimize import minimize_scalar  # loaded by fits only, as _max_likelihood

    _, recent = recent_series(t, resid, sigma, model.recent_time_constant, 0.0, 0.0,
                              model.max_gap)
    ok = np.isfinite(resid) & np.isfinite(sigma) & (sigma > 0.0)
    r2, e = resid[ok] ** 2, recent[ok]
    noise2 = model.noise ** 2
    terms = np.maximum(sigma[ok] ** 2 - noise2, 0.0)  # the model terms' variance

    def nll(w: float) -> float:
        v = noise2 + (1.0 - w + w * e) * terms + 1e-300
        return float(np.sum(0.5 * np.log(v) + 0.5 * r2 / v))

    w = float(minimize_scalar(nll, bounds=(0.0, 1.0), method="bounded",
                              options={"xatol": 1e-9}).x)
    scale = _calibration(np.sqrt(r2) / Z95, noise2, (1.0 - w + w * e) * terms)
    scale = scale or 1.0  # 0: the noise alone holds 95 % (nothing to scale)
    return replace(model, recent_weight=min(max(w, 0.0), 1.0), recent_scale=scale,
                   recent_mean_weight=0.0)


def sensor_noise(torque: np.ndarray, resid: np.ndarray) -> float:
    """Return the residual's std [N m] where ``torque`` (``|modelled|``) is quiet (docstring).

    Robust: from the median of the squared residuals (``/ 0.4549``, the median of a
    chi-squared variable of one degree of freedom), so the few zero crossings of a reversal
    among the quiet samples do not count as noise. 0 when fewer than 20 samples are quiet
    (the constant ``base`` then carries the floor).
    """
    quiet = torque <= QUIET_FRACTION * float(np.max(torque))
    if quiet.sum() < 20:
        return 0.0
    return float(np.sqrt(np.median(resid[quiet] ** 2) / CHI2_1_MEDIAN))


def _max_likelihood(design: np.ndarray, resid: np.ndarray, noise: float) -> np.ndarray:
    """Return the >= 0 coefficients maximising the Gaussian likelihood of ``resid``."""
    from scipy.optimize import minimize  # loaded by fits only: `clutch replay` starts without

    scale = np.sqrt(np.mean(design ** 2, axis=0))
    used = scale > 0.0  # a feature the run lacks (no stick, no rate) keeps its term at 0
    x = design[:, used] / scale[used]
    r2 = resid ** 2
    floor = noise ** 2 + 1e-12 * float(np.mean(r2)) + 1e-300

    def nll(log_c: np.ndarray) -> tuple[float, np.ndarray]:
        c2 = np.exp(2.0 * log_c)
        var = floor + (x ** 2) @ c2
        g = 0.5 / var - 0.5 * r2 / var ** 2  # d nll / d var per sample
        return (float(np.sum(0.5 * np.log(var) + 0.5 * r2 / var)),
                2.0 * c2 * ((x ** 2).T @ g))

    level = 0.5 * math.log(float(np.mean(r2)) / x.shape[1] + 1e-300)
    bounds = [(level - 40.0, level + 20.0)] * x.shape[1]
    # several starts (the likelihood has local minima where one term takes everything):
    # equal shares, then each term carrying nearly all the variance; the lowest wins
    starts = [np.full(x.shape[1], level)]
    for j in range(x.shape[1]):
        start = np.full(x.shape[1], level - 3.0)
        start[j] = level + 0.5 * math.log(x.shape[1])
        starts.append(start)
    fits = [minimize(nll, s0, jac=True, method="L-BFGS-B", bounds=bounds) for s0 in starts]
    best = min(fits, key=lambda f: float(f.fun))
    coef = np.zeros(design.shape[1])
    coef[used] = np.exp(best.x) / scale[used]
    return coef


def _calibration(ratio: np.ndarray, noise2: float, terms: np.ndarray) -> float:
    """Return ``k``: 95 % of ``ratio`` (``|r| / 1.96``) below ``sqrt(noise2 + k^2 terms)``."""
    def inside(k: float) -> float:
        return float(np.mean(ratio ** 2 <= noise2 + k * k * terms))

    if inside(0.0) >= 0.95 or not np.any(terms > 0.0):
        return 0.0 if np.any(terms > 0.0) else 1.0
    return smallest_scale(inside, 60)  # bisection to ~1e-18 relative: deterministic


def phases(t: np.ndarray, pressure: np.ndarray, slip: np.ndarray) -> np.ndarray:
    """Return True where a sample is transient (module docstring's phase definition)."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(pressure, dtype=float)
    s = np.asarray(slip, dtype=float)
    span = float(np.nanmax(p) - np.nanmin(p)) if np.isfinite(p).any() else 0.0
    back = np.maximum(np.searchsorted(t, t - RATE_SPAN, side="right") - 1, 0)
    dt = t - t[back]
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.abs(p - p[back]) / np.where(dt > 0, dt, np.nan)
    marker = np.zeros(t.size, dtype=bool)
    if span > 0:
        marker = rate > TRANSIENT_RATE * span
    sign = np.where(np.abs(s) > SLIP_DEADBAND, np.sign(s), 0.0)
    last_sign = 0.0
    for i in range(t.size):  # a reversal: the sign outside the deadband changed
        if sign[i] != 0.0:
            marker[i] |= last_sign != 0.0 and sign[i] != last_sign
            last_sign = sign[i]
    out = np.zeros(t.size, dtype=bool)
    last = -math.inf
    for i in range(t.size):
        if marker[i]:
            last = t[i]
        out[i] = t[i] - last <= TRANSIENT_WINDOW
    return out


def negative_log_likelihood(measured: np.ndarray, modelled: np.ndarray,
                            std: np.ndarray) -> float:
    """Mean Gaussian negative log-likelihood [nats per sample] of the residuals under ``std``.

    ``log(std) + r^2 / (2 std^2) + log(2 pi) / 2`` averaged over the samples with a finite
    residual and a finite std > 0 (NaN when there is none): a held-out score of an error model
    that rewards a band as narrow as the errors allow, not just its coverage.
    """
    resid = np.asarray(measured, dtype=float) - np.asarray(modelled, dtype=float)
    std = np.asarray(std, dtype=float)
    ok = np.isfinite(resid) & np.isfinite(std) & (std > 0.0)
    if not ok.any():
        return math.nan
    r, s = resid[ok], std[ok]
    return float(np.mean(np.log(s) + 0.5 * (r / s) ** 2) + 0.5 * math.log(2.0 * math.pi))


def coverage(measured: np.ndarray, modelled: np.ndarray, std: np.ndarray,
             transient: np.ndarray) -> dict[str, Any]:
    """Fraction of measured samples inside ``modelled +- 1.96 std``: overall, per phase.

    Returns:
        ``{"coverage_95": f, "coverage_95_transient": f, "coverage_95_steady": f,
        "coverage_samples": n, "coverage_transient_samples": n}`` (NaN fraction when a phase
        has no measured sample).

    """
    measured = np.asarray(measured, dtype=float)
    resid = np.abs(measured - np.asarray(modelled, dtype=float))
    std = np.asarray(std, dtype=float)
    ok = np.isfinite(resid) & np.isfinite(std)
    inside = resid <= Z95 * std
    transient = np.asarray(transient, dtype=bool)

    def frac(mask: np.ndarray) -> float:
        n = int(mask.sum())
        return float(inside[mask].sum() / n) if n else math.nan

    return {
        "coverage_95": frac(ok),
        "coverage_95_transient": frac(ok & transient),
        "coverage_95_steady": frac(ok & ~transient),
        "coverage_samples": int(ok.sum()),
        "coverage_transient_samples": int((ok & transient).sum()),
    }
