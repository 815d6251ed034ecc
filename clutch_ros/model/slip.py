"""Slip speed: ω_diff from wheel (Eq. 4) or shaft speeds, ω_base, and the filtered Diff Omega.

All speeds in rad/s. ω_diff = ω_input − ω_output (thesis 2.1.1, item 8); on a vehicle the
input is the front axle and the output the rear axle, hence Eq. 4.

:class:`SlipFilter` is the "filtered Diff Omega" of thesis 3.2, the slip speed the friction
model uses: a first-order low pass ``1/(τ s + 1)``, discretised exactly for a variable sample
time under the convention used throughout the model core: a sample's value is held over the
interval that ends at its stamp, so ``y_k = y_{k−1} + (1 − e^{−dt/τ}) (u_k − y_{k−1})``.
The first sample initialises the filter to its value; τ = 0 passes the input through.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from clutch_ros.model.errors import InputError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray

__all__ = [
    "slip_speed_from_wheels",
    "slip_speed_from_shafts",
    "base_speed",
    "SlipFilter",
    "lowpass_series",
]


@overload
def slip_speed_from_wheels(fl: float, fr: float, rl: float, rr: float) -> float: ...
@overload
def slip_speed_from_wheels(fl: ArrayLike, fr: ArrayLike, rl: ArrayLike,
                           rr: ArrayLike) -> FloatArray: ...
def slip_speed_from_wheels(fl: Any, fr: Any, rl: Any, rr: Any) -> Any:
    """Return Eq. 4: ω_diff = (ω_FR + ω_FL)/2 − (ω_RR + ω_RL)/2 [rad/s] (scalars or arrays)."""
    return (np.add(fr, fl) - np.add(rr, rl)) / 2.0 if np.ndim(fl) else (fr + fl) / 2.0 - (
        rr + rl) / 2.0


@overload
def slip_speed_from_shafts(input_speed: float, output_speed: float) -> float: ...
@overload
def slip_speed_from_shafts(input_speed: ArrayLike, output_speed: ArrayLike) -> FloatArray: ...
def slip_speed_from_shafts(input_speed: Any, output_speed: Any) -> Any:
    """Return ω_diff = ω_input − ω_output [rad/s]."""
    return np.subtract(input_speed, output_speed) if np.ndim(input_speed) else (
        input_speed - output_speed)


@overload
def base_speed(input_speed: float, output_speed: float) -> float: ...
@overload
def base_speed(input_speed: ArrayLike, output_speed: ArrayLike) -> FloatArray: ...
def base_speed(input_speed: ArrayLike, output_speed: ArrayLike) -> float | FloatArray:
    """Return ω_base ≥ 0: the lower of the two shaft speed magnitudes [rad/s] (thesis 2.1.1).

    The other shaft then turns at ω_base + |ω_diff| when both turn the same way.
    """
    out = np.minimum(np.abs(input_speed), np.abs(output_speed))
    return float(out) if np.ndim(out) == 0 else out


def _alpha(dt: float, tau: float) -> float:
    return 1.0 if tau <= 0.0 else -math.expm1(-dt / tau)


class SlipFilter:
    """First-order low pass of the slip speed, exact for variable dt (module docstring).

    Args:
        time_constant: τ [s], ≥ 0 (0 = no filtering).

    """

    def __init__(self, time_constant: float) -> None:
        if not (math.isfinite(time_constant) and time_constant >= 0.0):
            raise InputError(f"slip filter time constant must be finite and >= 0, got "
                             f"{time_constant!r}")
        self.time_constant = float(time_constant)
        self._value: float | None = None

    @property
    def value(self) -> float | None:
        """Current filtered slip speed [rad/s], None before the first sample."""
        return self._value

    def reset(self, value: float | None = None) -> None:
        """Forget the history; the next :meth:`update` (or ``value`` if given) initialises."""
        self._value = None if value is None else float(value)

    def update(self, dt: float, slip_speed: float) -> float:
        """Advance by ``dt`` [s] (> 0) with the new sample ``slip_speed`` [rad/s]; return y."""
        if self._value is None:
            self._value = float(slip_speed)
            return self._value
        if not dt > 0.0:
            raise InputError(f"slip filter needs dt > 0, got {dt!r}")
        y = self._value
        self._value = y + _alpha(dt, self.time_constant) * (slip_speed - y)
        return self._value


def lowpass_series(t: ArrayLike, u: ArrayLike, time_constant: float) -> FloatArray:
    """Filter ``u`` at stamps ``t`` [s] exactly as repeated :meth:`SlipFilter.update` calls.

    ``u[0]`` initialises the filter (as the first update does); same float operations, so the
    result equals the per-sample loop bit for bit.
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    out = np.array(u, dtype=float, copy=True)
    tau = float(time_constant)
    if u.size == 0 or tau <= 0.0:
        return out
    dts = np.diff(t).tolist()
    uu = u.tolist()
    y = uu[0]
    vals = [y]
    for dt, x in zip(dts, uu[1:]):
        y = y + _alpha(dt, tau) * (x - y)
        vals.append(y)
    out[:] = vals
    return out
