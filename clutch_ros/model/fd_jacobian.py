"""Finite-difference Jacobian of the fit's residuals that a jump in one residual cannot spoil.

Why: the fit's residuals are piecewise smooth in the parameters, not smooth. With the
drivetrain compliance (:mod:`~clutch_ros.model.compliance`) a sticking clutch breaks away when
its torque reaches the static capacity T_s and then carries the kinetic one T_k < T_s, so the
modelled torque *at a sample stamp* jumps by T_s − T_k (~140 N m on the golden runs) when a
parameter moves the break-away instant across that stamp. The least-squares optimum of such
a fit sits against that edge (the measured torque keeps rising, so the fit delays the
break-away until the sample is just still stuck). A one-sided difference whose step crosses
the edge then holds ``jump / h`` (~1.4e5 N m per unit for h = 1e-3) in that row instead of
a slope, the same spike in every column that crosses it: the columns turn collinear, the
rank check sees a singular value ratio of ~5e-5 instead of ~0.04, and the solver takes steps
from a Jacobian that is mostly that spike. Which columns cross is decided by where the
optimiser happened to stop, i.e. by round-off: a change of the model at the 1e-9 level
(closed-form ``e^{A dt}`` instead of ``expm``) flipped the coulomb fit's verdict.

How: both one-sided differences of every column, ``D+ = (f(z + h) − f(z)) / h`` and
``D− = (f(z) − f(z − h)) / h`` (clipped at the bounds). Element by element, where they agree
(same sign, within a factor :data:`AGREE`) the central difference (the secant over both
steps, O(h²)) is taken; where they do
not, one side crossed a jump (its magnitude ~jump / h, far above a slope) and the side of
smaller magnitude is taken: the slope of the smooth piece the point lies on. A smooth residual
gets the central difference (its sides differ by ~h |f''|, far inside :data:`AGREE` for
h = 1e-3 and O(1) variables); a residual with a jump within h of the point gets the slope on
the point's side, whichever side round-off put the point on. A parameter within h / 2 of a
bound (a difference over the sliver up to it would be round-off) gets D1 over
``[z, z + h]`` and D2 over ``[z + h, z + 2 h]``, away from the bound, and the same rule with D1
where they agree. The cost: 2 n evaluations per Jacobian instead of scipy's n forward
differences.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

import numpy as np

from clutch_ros.model.arraytypes import FloatArray

__all__ = ["AGREE", "jump_robust_jacobian", "JacobianOf"]

#: one-sided differences within this factor of each other (same sign) "agree": a smooth
#: residual's sides differ by h |f''| ≪ |f'|; a jump makes one of them ~jump / h
AGREE = 2.0


class _BoundedResiduals(Protocol):
    lower: FloatArray
    upper: FloatArray

    def __call__(self, z: FloatArray, /) -> FloatArray: ...


Mapper = Callable[[Callable[[FloatArray], FloatArray], list[FloatArray]], Iterable[FloatArray]]


def jump_robust_jacobian(problem: _BoundedResiduals, z: FloatArray, step: float,
                         f0: FloatArray | None = None, map_: Mapper = map) -> FloatArray:
    """Jacobian of ``problem`` at ``z`` (module docstring), steps ``step`` within the bounds.

    ``f0``: ``problem(z)`` when known (else evaluated). ``map_``: how the 2 n evaluations are
    run (e.g. a thread pool's ``map``); the result is the same bits either way.
    """
    z = np.asarray(z, dtype=float)
    base = problem(z) if f0 is None else np.asarray(f0, dtype=float)
    points: list[FloatArray] = []
    plans: list[tuple[float, float, bool]] = []
    for i in range(z.size):
        up, down = problem.upper[i] - z[i], z[i] - problem.lower[i]
        if min(up, down) >= 0.5 * step:  # both sides: z + h, z - h
            offsets = (min(step, up), -min(step, down), True)
        else:  # near a bound (a difference over a sliver is round-off): z + h, z + 2 h inward
            h = min(step, 0.5 * max(up, down))
            h = h if up >= down else -h
            offsets = (h, 2.0 * h, False)
        for off in offsets[:2]:
            zi = z.copy()
            zi[i] += off
            points.append(zi)
        plans.append(offsets)
    values = list(map_(problem, points))
    cols = []
    for i, (a, b, two_sided) in enumerate(plans):
        fa, fb = values[2 * i], values[2 * i + 1]
        if two_sided:  # D+ over [z, z + a], D− over [z + b, z]
            cols.append(_combine((fa - base) / a, (base - fb) / -b, a, -b))
        else:  # one-sided: D1 at z (as forward differences), D2 one step further checks it
            d1, d2 = (fa - base) / a, (fb - fa) / a
            cols.append(_combine(d1, d2, 1.0, 0.0))
    return np.column_stack(cols)


def _combine(d1: FloatArray, d2: FloatArray, w1: float, w2: float) -> FloatArray:
    """``(w1 d1 + w2 d2) / (w1 + w2)`` where the two agree, else the one of smaller magnitude.

    Two-sided: ``d1``, ``d2`` = D+, D− and the weights their widths (the secant over both);
    one-sided: ``w2`` = 0 (D1 where it agrees with the difference one step further).
    """
    blend = (d1 * w1 + d2 * w2) / (w1 + w2)
    a, b = np.abs(d1), np.abs(d2)
    agree = (np.sign(d1) == np.sign(d2)) & (a <= AGREE * b) & (b <= AGREE * a)
    return np.where(agree, blend, np.where(a <= b, d1, d2))


class JacobianOf:
    """``jac`` callable for :func:`scipy.optimize.least_squares` using the last ``f(z)``.

    Wraps ``problem``: call the instance for the residuals (it remembers the last point and
    value), pass :meth:`jacobian` as ``jac``; the solver asks for the Jacobian at the point it
    just evaluated, so ``f(z)`` is not computed again.
    """

    def __init__(self, problem: _BoundedResiduals, step: float, map_: Mapper = map) -> None:
        self.problem = problem
        self.lower, self.upper = problem.lower, problem.upper
        self.step = step
        self.map = map_
        self._last: tuple[FloatArray, FloatArray] | None = None

    def __call__(self, z: FloatArray) -> FloatArray:
        """Return the residuals at ``z`` (and remember them for :meth:`jacobian`)."""
        f = self.problem(z)
        self._last = (np.array(z, dtype=float), f)
        return f

    def jacobian(self, z: FloatArray) -> FloatArray:
        """Return the Jacobian at ``z`` (``f(z)`` re-used when ``z`` was the last point)."""
        z = np.asarray(z, dtype=float)
        last = self._last
        f0 = last[1] if last is not None and np.array_equal(last[0], z) else None
        return jump_robust_jacobian(self.problem, z, self.step, f0, self.map)
