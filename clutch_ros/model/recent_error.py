"""The recent measured error of the torque band: its offset and its spread.

With a torque sensor the node knows how wrong the model has just been, and the model's error
is mostly an offset held for seconds (a friction hysteresis after a pressure change, the same
across noise seeds). :class:`RecentResidual` keeps two causal low-pass filters over the
*previous* measured samples (restarted at the first sample and after a gap above
``max_gap`` [s]; held while no measurement comes):

* ``M`` [N m]: the low-pass (``mean_time_constant`` [s]) of the residual ``r = measured -
  modelled``, the offset the model has been off by lately (0 before the first sample and
  after a gap);
* ``E`` [1]: the low-pass (``time_constant`` [s]) of ``u^2``, ``u = (r - g M) / sigma`` the
  standardised innovation (what the offset did not predict; 1 before the first sample and
  after a gap), ``g`` = ``mean_weight``.

The residual of the next sample is then predicted as normal, ``N(g M, v)`` (``v`` from ``E``,
:mod:`clutch_ros.model.uncertainty`). The band is centred on ``modelled_torque``, not on
``modelled + g M``, so the published std is the one of a zero-mean normal with the same central
95 % interval: ``h / 1.96`` with ``h`` the half width for which ``N(g M, v)`` puts 95 % in
``[-h, h]`` (:func:`central_half_width`; ``h = 1.96 sqrt(v)`` at ``g M = 0``, ``|g M| +
1.645 sqrt(v)`` for a large offset). A band ``1.96 sqrt(M^2 + v)`` (the offset folded into the
variance) would cover a held offset with room to spare (a single step's 10 s hold: 99 %).

:func:`fit_recent` identifies ``g`` and the weight ``w`` of ``E`` by Gaussian maximum
likelihood of ``N(g M, v)`` on the fitting runs, then the factor of the model terms
(``recent_scale``) so that 95 % of the fitting runs' residuals lie within ``+-h``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from clutch_ros.model.errors import ModelError

__all__ = ["RecentResidual", "central_half_width", "central_half_widths", "fit_recent",
           "recent_series", "smallest_scale"]

#: Two-sided 95 % quantile of the normal distribution (as uncertainty.Z95).
_Z95 = 1.959963984540054
_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


class RecentResidual:
    """The low-pass ``M`` and ``E`` of the previous measured samples (module docstring).

    ``time_constant`` (of ``E``), ``mean_time_constant`` (of ``M``; 0: ``M`` is the last
    residual) and ``max_gap`` [s]; ``mean_weight`` ``g`` [1].
    """

    def __init__(self, time_constant: float, mean_time_constant: float, mean_weight: float,
                 max_gap: float):
        """Start with the prior (``E`` = 1, ``M`` = 0)."""
        self.tc, self.tm, self.g, self.max_gap = (time_constant, mean_time_constant,
                                                  mean_weight, max_gap)
        self.t = math.nan
        self.value = 1.0
        self.mean = 0.0

    def _fresh(self, t: float) -> bool:
        dt = t - self.t
        return not math.isfinite(self.t) or 0.0 <= dt <= self.max_gap

    def at(self, t: float) -> float:
        """Return ``E`` for a sample at ``t`` [s]: the prior 1 after a gap above ``max_gap``."""
        return self.value if self._fresh(t) else 1.0

    def mean_at(self, t: float) -> float:
        """Return ``M`` [N m] for a sample at ``t`` [s]: 0 after a gap above ``max_gap``."""
        return self.mean if self._fresh(t) else 0.0

    def update(self, t: float, resid: float, sigma: float) -> None:
        """Feed one sample's residual [N m] under its ``sigma`` [N m] (NaN: no measurement)."""
        if not (math.isfinite(resid) and sigma > 0.0):
            return  # no measurement: M and E hold
        dt = t - self.t
        if not (math.isfinite(dt) and 0.0 < dt <= self.max_gap):
            self.value, self.mean = 1.0, 0.0  # first sample, a gap or a step back: the prior
            dt = 0.0
        z = (resid - self.g * self.mean) / sigma
        self.value += (dt / (self.tc + dt) if self.tc > 0.0 else 1.0) * (z * z - self.value)
        self.mean += (dt / (self.tm + dt) if self.tm > 0.0 else 1.0) * (resid - self.mean)
        self.t = t


def central_half_width(mean: float, sd: float) -> float:
    """Return ``h`` [N m]: ``N(mean, sd^2)`` puts 95 % of its mass in ``[-h, h]``.

    Newton's method on ``Phi((h - mean)/sd) + Phi((h + mean)/sd) - 1.95``, concave and
    increasing for ``h >= |mean|``, from ``|mean| + 1.96 sd`` above the root (so every step
    stays above it and the iteration cannot overshoot). ``1.96 sd`` at ``mean`` 0.
    """
    if mean == 0.0 or sd <= 0.0:
        return _Z95 * sd + abs(mean)
    a = abs(mean)
    h = a + _Z95 * sd
    for _ in range(50):
        x1, x2 = (h - a) / sd, (h + a) / sd
        f = 0.5 * (math.erf(x1 / _SQRT2) + math.erf(x2 / _SQRT2)) - 0.95
        slope = (math.exp(-0.5 * x1 * x1) + math.exp(-0.5 * x2 * x2)) * _INV_SQRT_2PI / sd
        step = f / slope
        h -= step
        if abs(step) <= 1e-13 * h:
            break
    return h


def central_half_widths(mean: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """:func:`central_half_width` of arrays (the fit's calibration; the same iteration)."""
    from scipy.special import erf  # fits only

    a = np.abs(np.asarray(mean, dtype=float))
    sd = np.asarray(sd, dtype=float)
    h: np.ndarray = a + _Z95 * sd
    live = (a > 0.0) & (sd > 0.0)
    for _ in range(50):
        x1, x2 = (h[live] - a[live]) / sd[live], (h[live] + a[live]) / sd[live]
        f = 0.5 * (erf(x1 / _SQRT2) + erf(x2 / _SQRT2)) - 0.95
        slope = (np.exp(-0.5 * x1 * x1) + np.exp(-0.5 * x2 * x2)) * _INV_SQRT_2PI / sd[live]
        step = f / slope
        h[live] -= step
        if not np.any(np.abs(step) > 1e-13 * h[live]):
            break
    return h


def recent_series(t: np.ndarray, resid: np.ndarray, sigma: np.ndarray, time_constant: float,
                  mean_time_constant: float, mean_weight: float,
                  max_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``M`` and ``E`` of every sample (before its own residual), as the node's loop."""
    rec = RecentResidual(time_constant, mean_time_constant, mean_weight, max_gap)
    n = len(t)
    mean, value = np.empty(n), np.empty(n)
    for i in range(n):
        ti = float(t[i])
        mean[i], value[i] = rec.mean_at(ti), rec.at(ti)
        rec.update(ti, float(resid[i]), float(sigma[i]))
    return mean, value


def fit_recent(t: np.ndarray, resid: np.ndarray, sigma: np.ndarray, noise: float,
               time_constant: float, mean_time_constant: float,
               max_gap: float) -> tuple[float, float, float]:
    """Return ``(mean_weight, weight, scale)`` identified on runs (module docstring).

    ``t`` [s], ``resid`` [N m] (NaN: no measurement), ``sigma`` [N m] (the static terms in
    quadrature, NaN where none), ``noise`` [N m] the sensor's part of ``sigma``. ``g`` and
    ``w`` maximise the Gaussian likelihood of ``N(g M, v)``, ``v = noise^2 + (1 - w + w E)
    (sigma^2 - noise^2)``, over [0, 1]^2 (Nelder-Mead from (0.5, 0.9), deterministic); the
    scale then puts 95 % of the residuals within ``+-h`` of ``N(g M, noise^2 + scale^2 (1 - w
    + w E)(sigma^2 - noise^2))``.

    Raises:
        ModelError: fewer than 20 samples with a residual and a ``sigma`` > 0.

    """
    from scipy.optimize import minimize  # fits only

    ok = np.isfinite(resid) & np.isfinite(sigma) & (sigma > 0.0)
    if ok.sum() < 20:
        raise ModelError(f"the recent error needs at least 20 measured samples, got {ok.sum()}")
    noise2 = noise * noise
    terms = np.maximum(sigma[ok] ** 2 - noise2, 0.0)
    r = resid[ok]

    def parts(g: float) -> tuple[np.ndarray, np.ndarray]:
        mean, value = recent_series(t, resid, sigma, time_constant, mean_time_constant, g,
                                    max_gap)
        return g * mean[ok], value[ok]

    def nll(x: np.ndarray) -> float:
        g, w = (min(max(float(v), 0.0), 1.0) for v in x)
        mu, e = parts(g)
        v = noise2 + (1.0 - w + w * e) * terms + 1e-300
        return float(np.sum(0.5 * np.log(v) + 0.5 * (r - mu) ** 2 / v))

    best = minimize(nll, np.array([0.5, 0.9]), method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-6})
    g, w = (min(max(float(v), 0.0), 1.0) for v in best.x)
    mu, e = parts(g)
    spread = (1.0 - w + w * e) * terms

    def inside(k: float) -> float:
        return float(np.mean(np.abs(r) <= central_half_widths(mu, np.sqrt(noise2 + k * k
                                                                              * spread))))

    if inside(0.0) >= 0.95 or not np.any(spread > 0.0):
        return g, w, 1.0  # the noise alone holds 95 % (nothing to scale)
    return g, w, smallest_scale(inside, 50)


def smallest_scale(inside: Callable[[float], float], iterations: int) -> float:
    """Return the smallest ``k`` > 0 with ``inside(k) >= 0.95`` (``inside(0)`` below it).

    Doubling from 1, then ``iterations`` bisections (deterministic; 50: ~1e-15 relative).
    """
    low, high = 0.0, 1.0
    while inside(high) < 0.95:
        low, high = high, 2.0 * high
    for _ in range(iterations):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if inside(mid) < 0.95 else (low, mid)
    return high
