"""Steady-state error of a closed-loop run: how far each settled request plateau sits off.

Definition (the ``steady_state_error`` figure of ``clutch demo --json`` and ``clutch
closed-loop``): over every request plateau (a stretch of constant request) at least
``min_duration`` (1 s) long and at least ``min_fraction`` (10 %) of the rated torque, take
``|mean measured torque over the plateau's last window (0.5 s) / request - 1|``; the figure is
the largest over all plateaus. Plateaus are found in the profile (:class:`Segment` list), so
a hold that follows a ramp to the same value counts from the ramp's end. Units: time [s],
torque [N m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Plateau", "PlateauFigure", "plateau_errors", "request_plateaus",
           "steady_state_error"]


@dataclass(frozen=True)
class Plateau:
    """A stretch of constant request: ``start``..``end`` [s] at ``request`` [N m]."""

    start: float
    end: float
    request: float

    @property
    def duration(self) -> float:
        """Length of the plateau [s]."""
        return self.end - self.start


@dataclass(frozen=True)
class PlateauFigure:
    """One plateau's figure: the mean measured torque over its last window [N m], the error."""

    plateau: Plateau
    mean_measured: float
    error: float
    samples: int


def request_plateaus(profile, *, min_duration: float = 1.0, min_request: float = 0.0
                     ) -> list[Plateau]:
    """Return the maximal constant-request stretches of ``profile`` that qualify.

    Consecutive segments with one constant value (a hold after a ramp ending there, or two
    holds of the same value) merge into one plateau. Only plateaus ``>= min_duration`` [s]
    and with ``request >= min_request`` [N m] (and > 0) are returned.
    """
    out: list[Plateau] = []
    elapsed = 0.0
    current: list[float] | None = None  # [start, end, value]
    for seg in profile:
        start, end = elapsed, elapsed + seg.duration
        elapsed = end
        if seg.is_hold:
            if current is not None and current[2] == seg.start and current[1] == start:
                current[1] = end
            else:
                if current is not None:
                    out.append(Plateau(*current))
                current = [start, end, float(seg.start)]
        elif current is not None:
            out.append(Plateau(*current))
            current = None
    if current is not None:
        out.append(Plateau(*current))
    return [p for p in out if p.duration >= min_duration - 1e-9 and p.request > 0.0
            and p.request >= min_request]


def plateau_errors(profile, time, measured, rated_torque: float, *, min_duration: float = 1.0,
                   min_fraction: float = 0.10, window: float = 0.5) -> list[PlateauFigure]:
    """Return the error of every qualifying plateau (module docstring).

    ``time`` [s] is on the profile's clock, ``measured`` [N m] the measured torque (NaN where
    missing; those samples are left out). A plateau without a finite sample in its window
    gives a NaN error.
    """
    t = np.asarray(time, dtype=float)
    meas = np.asarray(measured, dtype=float)
    rows = []
    for plateau in request_plateaus(profile, min_duration=min_duration,
                                    min_request=min_fraction * rated_torque):
        inside = (t >= plateau.end - window) & (t < plateau.end) & np.isfinite(meas)
        n = int(inside.sum())
        mean = float(meas[inside].mean()) if n else math.nan
        rows.append(PlateauFigure(plateau, mean, abs(mean / plateau.request - 1.0), n))
    return rows


def steady_state_error(profile, time, measured, rated_torque: float, **kwargs) -> float:
    """Return the largest plateau error (module docstring); NaN without a plateau/sample."""
    errors = [row.error for row in plateau_errors(profile, time, measured, rated_torque,
                                                  **kwargs)]
    if not errors or any(math.isnan(e) for e in errors):
        return math.nan
    return float(max(errors))
