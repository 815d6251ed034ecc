"""Torque uncertainty: the 1-sigma prediction error of ``modelled_torque`` [N m].

An error model on the estimator's own outputs (it uses residuals only, so it is re-identified
after any change of the model). Per sample, causally (the node computes it sample by sample,
the replay with the same loop, :func:`torque_std`):

* ``T`` = ``|modelled_torque|`` [N m];
* ``R`` = ``|dT/dt|`` low-pass filtered with ``time_constant`` [N m/s] (first order, the
  backward difference of the modelled torque; a gap above ``max_gap`` restarts it at 0);
* ``S`` = 1 while the clutch sticks (``|slip_speed_filtered| < stick_speed``), else 0.

    sigma = base + rel * T + rate_time * R + stick_rel * S * T

:func:`fit_error_model` identifies ``base`` [N m], ``rel`` [1], ``rate_time`` [s] and
``stick_rel`` [1] on a fitting run: a non-negative least-squares fit of the absolute
residuals (``|measured - modelled| * sqrt(pi / 2)``, whose mean is sigma for a normal error)
on the four features, reweighted by ``1 / sigma`` (so each sample's relative misfit counts
alike, not only the largest errors), then one quantile calibration of the whole so that
95 % of the fitting run's ``|residual| / sigma`` are below 1.96. The parameters live in the
parameter file under ``uncertainty.*`` (:data:`DEFAULTS` when absent).

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

__all__ = [
    "DEFAULTS",
    "ErrorModel",
    "TRANSIENT_RATE",
    "TRANSIENT_WINDOW",
    "RATE_SPAN",
    "SLIP_DEADBAND",
    "Z95",
    "coverage",
    "features",
    "fit_error_model",
    "phases",
    "torque_std",
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


@dataclass(frozen=True)
class ErrorModel:
    """Parameters of the torque error model (module docstring), SI units.

    Attributes:
        base: constant part [N m], >= 0.
        rel: part proportional to ``|modelled_torque|`` [1], >= 0.
        rate_time: part proportional to the filtered ``|dT/dt|`` [s], >= 0.
        stick_rel: extra part proportional to the torque while the clutch sticks [1], >= 0.
        time_constant: low-pass time constant of the torque rate [s], > 0.
        stick_speed: slip speed below which the clutch counts as sticking [rad/s], > 0.
        max_gap: a time step above it (or not positive) restarts the rate filter [s], > 0.

    """

    base: float = 5.0
    rel: float = 0.1
    rate_time: float = 0.05
    stick_rel: float = 0.0
    time_constant: float = 0.1
    stick_speed: float = 0.1
    max_gap: float = 0.5

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            positive = name in ("time_constant", "stick_speed", "max_gap")
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
    """Return the (n, 3) features ``T``, ``R``, ``S`` (module docstring) of every sample.

    ``t`` [s], ``modelled`` [N m], ``slip`` = ``slip_speed_filtered`` [rad/s]. Non-finite
    torques give NaN rows and leave the filter as it was.
    """
    t = np.asarray(t, dtype=float)
    modelled = np.asarray(modelled, dtype=float)
    slip = np.asarray(slip, dtype=float)
    out = np.full((t.size, 3), np.nan)
    state = _RateFilter(model)
    for i in range(t.size):
        rate = state.update(float(t[i]), float(modelled[i]))
        if not math.isnan(rate):
            out[i] = (abs(modelled[i]), rate, float(abs(slip[i]) < model.stick_speed))
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


def _sigma(model: ErrorModel, torque: float, rate: float, stick: float) -> float:
    return (model.base + model.rel * torque + model.rate_time * rate
            + model.stick_rel * stick * torque)


class TorqueStd:
    """Per-sample ``modelled_torque_std`` [N m] for the live node (same as :func:`torque_std`)."""

    def __init__(self, model: ErrorModel = DEFAULTS):
        """Start with an empty filter."""
        self.model = model
        self._filter = _RateFilter(model)

    def update(self, t: float, modelled: float, slip: float) -> float:
        """Return the std of one estimate (``t`` [s], torque [N m], slip [rad/s])."""
        rate = self._filter.update(t, modelled)
        if math.isnan(rate):
            return math.nan
        stick = 1.0 if abs(slip) < self.model.stick_speed else 0.0
        return _sigma(self.model, abs(modelled), rate, stick)


def torque_std(model: ErrorModel, t: np.ndarray, modelled: np.ndarray,
               slip: np.ndarray) -> np.ndarray:
    """Return ``modelled_torque_std`` [N m] of every sample, exactly as :class:`TorqueStd`."""
    est = TorqueStd(model)
    return np.array([est.update(float(a), float(b), float(c))
                     for a, b, c in zip(t, modelled, slip)], dtype=float)


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
    x, target = x[ok], np.abs(resid[ok]) * math.sqrt(math.pi / 2.0)
    design = np.column_stack([np.ones(len(x)), x[:, 0], x[:, 1], x[:, 2] * x[:, 0]])
    scale = np.maximum(np.sqrt(np.mean(design ** 2, axis=0)), 1e-300)
    floor = 1e-3 * float(np.mean(target)) + 1e-12  # never a zero-width band
    weight = np.ones(len(x))
    from scipy.optimize import nnls  # loaded by fits only: `clutch replay` starts without it

    for _ in range(4):
        coef, _ = nnls(design / scale * weight[:, None], target * weight)
        coef = coef / scale
        coef[0] = max(coef[0], floor)
        weight = 1.0 / (design @ coef)
    model = replace(base, base=float(coef[0]), rel=float(coef[1]),
                    rate_time=float(coef[2]), stick_rel=float(coef[3]))
    sigma = torque_std(model, t, modelled, slip)[ok]
    k = float(np.quantile(np.abs(resid[ok]) / sigma, 0.95)) / Z95
    return replace(model, base=model.base * k, rel=model.rel * k,
                   rate_time=model.rate_time * k, stick_rel=model.stick_rel * k)


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
