"""The demo's torque-request profile: steps and ramps up to the rated torque at 10 and 30 rpm.

A profile is a list of :class:`Segment` (piecewise-linear torque request [N m] at a slip speed
[rad/s] held by the rig motor); :func:`request_at` evaluates it. Rated torque is the estimator
preset's steady-state torque (Eq. 1) at ``rated_pressure`` and 35 °C.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Segment", "demo_profile", "request_at", "slip_at", "settled_mask"]

RPM = 2.0 * math.pi / 60.0  # [rad/s per rpm]


@dataclass(frozen=True)
class Segment:
    """Torque request ramping linearly from ``start`` to ``end`` [N m] over ``duration`` [s]."""

    duration: float
    start: float
    end: float
    slip_speed: float

    @property
    def is_hold(self) -> bool:
        """True when the request is constant over the segment."""
        return self.start == self.end


def demo_profile(rated_torque: float, quick: bool = False) -> list[Segment]:
    """Return the demo profile for ``rated_torque`` [N m]; ``quick`` shortens the holds."""
    hold = 2.0 if quick else 3.5
    ramp = 3.0 if quick else 5.0
    segments: list[Segment] = []
    for rpm in (10.0, 30.0):
        w = rpm * RPM
        t = rated_torque

        def add(duration, start, end, w=w):
            segments.append(Segment(duration, start, end, w))

        add(1.5, 0.0, 0.0)            # slip established, clutch open (DBP)
        add(hold, 0.5 * t, 0.5 * t)   # step up
        add(hold, 0.9 * t, 0.9 * t)   # incremented step
        add(hold, 0.3 * t, 0.3 * t)   # step down (rebound)
        add(ramp, 0.3 * t, 0.9 * t)   # ramp up
        add(1.0, 0.9 * t, 0.9 * t)
        add(ramp, 0.9 * t, 0.2 * t)   # ramp down
        add(1.0, 0.0, 0.0)
    return segments


def _locate(profile: list[Segment], t: float):
    elapsed = 0.0
    for seg in profile:
        if t < elapsed + seg.duration:
            return seg, t - elapsed
        elapsed += seg.duration
    return None, 0.0


def request_at(profile: list[Segment], t: float) -> float:
    """Torque request [N m] at profile time ``t`` [s]; 0 after the end."""
    seg, into = _locate(profile, t)
    if seg is None:
        return 0.0
    return seg.start + (seg.end - seg.start) * into / seg.duration


def slip_at(profile: list[Segment], t: float) -> float:
    """Slip speed [rad/s] the rig motor holds at profile time ``t``; the last one after."""
    seg, _ = _locate(profile, t)
    return profile[-1].slip_speed if seg is None else seg.slip_speed


def settled_mask(profile: list[Segment], t, settle_s: float = 1.0):
    """Boolean array: True where the request has been constant (a hold) for ``settle_s``.

    Ramps count as settled too once ``settle_s`` has passed since the ramp began, because a
    ramp is a tracking task; only the time right after a step is excluded.
    """
    t = np.asarray(t, dtype=float)
    mask = np.zeros(t.shape, dtype=bool)
    elapsed = 0.0
    previous_end = 0.0
    for seg in profile:
        inside = (t >= elapsed) & (t < elapsed + seg.duration)
        stepped = seg.start != previous_end
        settle = settle_s if stepped or seg.is_hold else 0.0
        mask |= inside & (t >= elapsed + settle) & (max(seg.start, seg.end) > 0.0)
        elapsed += seg.duration
        previous_end = seg.end
    return mask
