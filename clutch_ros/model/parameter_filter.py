"""The adaptation's estimator: recursive least squares with forgetting, bounds and covariance.

:class:`ParameterFilter` estimates the two parameters :mod:`clutch_ros.model.adaptation`
adapts (the friction scale and the relative spline gain) from one observation per sample,
``y = φᵀ θ + e`` with ``var(e) = R``, in covariance form:
``K = P φ / (φᵀ P φ + R)``, ``θ ← θ + K (y − φᵀ θ)``, ``P ← (I − K φᵀ) P (I − K φᵀ)ᵀ + K R Kᵀ``
(Joseph form), and before each update ``P ← P / λ`` with ``λ = exp(−dt / forgetting_time)``:
forgetting by the time that adaptation ran, so the memory is rate independent. With ``R`` the
variance of the torque error (``measurement_std² + (relative_std·|y|)²``) P is the
parameters' covariance; ``sqrt(P_ii)`` is the reported standard deviation. P never grows
above its prior (``initial_std²``): no covariance wind-up while excitation is poor. θ is
projected onto its bounds (scale in ``[scale_min, scale_max]``).

Units: θ and its standard deviations are dimensionless scales; φ, y and R carry the units of
the regression (adaptation: N m per unit scale, N m, (N m)²).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.errors import ModelError

if TYPE_CHECKING:
    from clutch_ros.model.arraytypes import FloatArray

__all__ = ["ParameterFilter"]


class ParameterFilter:
    """Recursive least squares with forgetting, bounds and covariance (module docstring).

    Two parameters (the friction scale and the relative spline gain), written out in plain
    floats: the update runs on every sample of a 1 kHz stream, where numpy's per-call
    overhead would cost more than the arithmetic.

    Args:
        theta: initial parameters (2 values)
        std: prior standard deviations (P starts at ``diag(std²)`` and its diagonal never
            exceeds that)
        lower, upper: bounds (2 values each)

    """

    def __init__(self, theta: Sequence[float], std: Sequence[float], lower: Sequence[float],
                 upper: Sequence[float]) -> None:
        if not (len(theta) == len(std) == len(lower) == len(upper) == 2):
            raise ModelError("ParameterFilter takes exactly two parameters")
        self.theta = [float(v) for v in theta]
        self.prior = [float(v) ** 2 for v in std]
        self.P = [[self.prior[0], 0.0], [0.0, self.prior[1]]]
        self.lower = [float(v) for v in lower]
        self.upper = [float(v) for v in upper]
        self.updates = 0

    @property
    def std(self) -> tuple[float, float]:
        """Standard deviations of the parameters, sqrt(diag P)."""
        return (math.sqrt(max(self.P[0][0], 0.0)), math.sqrt(max(self.P[1][1], 0.0)))

    def _inflation(self, i: int, forgetting: float) -> float:
        """Std factor of forgetting parameter ``i``: variance / λ, capped at the prior."""
        v = self.P[i][i]
        if v <= 0.0:
            return 1.0
        return math.sqrt(min(v / forgetting, self.prior[i]) / v)

    @property
    def covariance(self) -> FloatArray:
        """P as a 2 x 2 array."""
        return np.array(self.P)

    def update(self, phi: Sequence[float], y: float, noise_var: float, forgetting: float = 1.0,
               active: tuple[bool, bool] = (True, True)) -> float:
        """Fold in one observation ``y = φᵀθ + e``, var(e) = ``noise_var``; return y − φᵀθ.

        ``forgetting`` is λ in (0, 1]; ``active`` restricts the update to some parameters
        (the others, and their covariance, stay as they are). A non-finite input changes
        nothing (the innovation is returned as NaN).
        """
        h0, h1 = float(phi[0]), float(phi[1])
        th, P = self.theta, self.P  # noqa: N806 - P is the covariance
        innovation = y - h0 * th[0] - h1 * th[1]
        values = (h0, h1, y, noise_var, forgetting)
        if not (all(math.isfinite(v) for v in values) and noise_var > 0.0
                and 0.0 < forgetting <= 1.0):
            return math.nan
        a0, a1 = bool(active[0]), bool(active[1])
        if not (a0 or a1):
            return innovation
        # forgetting on the active parameters, variances capped at the prior (no wind-up)
        d0 = self._inflation(0, forgetting) if a0 else 1.0
        d1 = self._inflation(1, forgetting) if a1 else 1.0
        p00, p11, p01 = P[0][0] * d0 * d0, P[1][1] * d1 * d1, P[0][1] * d0 * d1
        if not a0:
            h0 = 0.0
        if not a1:
            h1 = 0.0
        ph0 = p00 * h0 + p01 * h1  # P h
        ph1 = p01 * h0 + p11 * h1
        s = h0 * ph0 + h1 * ph1 + noise_var
        # an inactive parameter gets no gain (Schmidt "consider" update): it stays, and the
        # Joseph form below keeps P symmetric and positive semi-definite for any gain
        k0 = ph0 / s if a0 else 0.0
        k1 = ph1 / s if a1 else 0.0
        m00, m01, m10, m11 = 1.0 - k0 * h0, -k0 * h1, -k1 * h0, 1.0 - k1 * h1
        q00 = m00 * p00 + m01 * p01
        q01 = m00 * p01 + m01 * p11
        q10 = m10 * p00 + m11 * p01
        q11 = m10 * p01 + m11 * p11
        P[0][0] = q00 * m00 + q01 * m01 + noise_var * k0 * k0
        P[0][1] = P[1][0] = q00 * m10 + q01 * m11 + noise_var * k0 * k1
        P[1][1] = q10 * m10 + q11 * m11 + noise_var * k1 * k1
        th[0] = min(max(th[0] + k0 * innovation, self.lower[0]), self.upper[0])
        th[1] = min(max(th[1] + k1 * innovation, self.lower[1]), self.upper[1])
        self.updates += 1
        return innovation
