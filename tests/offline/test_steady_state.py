"""The steady_state_error figure: plateaus from the profile, the last 0.5 s, the largest."""

import math

import numpy as np
import pytest

from clutch_ros.offline.steady_state import (
    Plateau,
    plateau_errors,
    request_plateaus,
    steady_state_error,
)
from clutch_ros.rig.request_profile import Segment, demo_profile

W = 1.0


def test_plateaus_merge_holds_and_skip_ramps_short_and_small():
    profile = [Segment(1.5, 0.0, 0.0, W), Segment(2.0, 500.0, 500.0, W),
               Segment(3.0, 500.0, 900.0, W), Segment(1.0, 900.0, 900.0, W),
               Segment(0.5, 300.0, 300.0, W), Segment(2.0, 50.0, 50.0, W)]
    assert request_plateaus(profile, min_duration=1.0, min_request=100.0) == [
        Plateau(1.5, 3.5, 500.0), Plateau(6.5, 7.5, 900.0)]


def test_error_is_the_largest_relative_mean_offset_over_the_last_window():
    profile = [Segment(2.0, 400.0, 400.0, W), Segment(2.0, 800.0, 800.0, W)]
    t = np.arange(0.0, 4.0, 0.001)
    measured = np.where(t < 2.0, 400.0 * 1.01, 800.0 * 0.97)
    measured[(t > 1.0) & (t < 1.4)] = 0.0  # outside the last 0.5 s: does not count
    rows = plateau_errors(profile, t, measured, rated_torque=1000.0)
    assert [r.samples for r in rows] == [500, 500]
    np.testing.assert_allclose([r.error for r in rows], [0.01, 0.03], rtol=1e-9)
    assert steady_state_error(profile, t, measured, 1000.0) == pytest.approx(0.03, rel=1e-9)


def test_demo_profile_plateaus():
    rated = 1233.0
    plateaus = request_plateaus(demo_profile(rated, quick=True), min_request=0.1 * rated)
    # per slip speed: 0.5, 0.9, 0.3 rated (2 s holds) and the 1 s hold after the ramp up
    assert [round(p.request / rated, 2) for p in plateaus] == [0.5, 0.9, 0.3, 0.9] * 2
    assert [p.duration for p in plateaus] == pytest.approx([2.0, 2.0, 2.0, 1.0] * 2)


def test_no_samples_gives_nan():
    profile = [Segment(2.0, 400.0, 400.0, W)]
    assert math.isnan(steady_state_error(profile, [0.1], [400.0], 1000.0))
