"""Slip speed from wheels (Eq. 4) and shafts, base speed, the exact slip filter."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    InputError,
    SlipFilter,
    base_speed,
    slip_speed_from_shafts,
    slip_speed_from_wheels,
)
from clutch_ros.model.slip import lowpass_series


def test_eq4():
    # front mean 10.5, rear mean 9.0 -> 1.5 rad/s; exact in binary floating point
    assert slip_speed_from_wheels(10.0, 11.0, 9.5, 8.5) == 1.5
    fl, fr, rl, rr = (np.array([10.0, 5.0]), np.array([11.0, 5.0]), np.array([9.5, 6.0]),
                      np.array([8.5, 6.0]))
    assert_allclose(slip_speed_from_wheels(fl, fr, rl, rr), [1.5, -1.0], rtol=0, atol=0)


def test_shafts_and_base_speed():
    assert slip_speed_from_shafts(105.0, 100.0) == 5.0
    assert slip_speed_from_shafts(100.0, 105.0) == -5.0
    assert base_speed(105.0, 100.0) == 100.0 and base_speed(-3.0, 7.0) == 3.0
    assert_allclose(base_speed(np.array([1.0, 9.0]), np.array([2.0, 3.0])), [1.0, 3.0])


def test_filter_matches_exponential_for_variable_dt():
    tau = 0.05
    filt = SlipFilter(tau)
    assert filt.update(0.0, 0.0) == 0.0  # first sample initialises
    rng = np.random.default_rng(1)
    dts = rng.uniform(1e-4, 3e-2, 200)
    t = np.cumsum(dts)
    out = [filt.update(dt, 2.0) for dt in dts]
    # exact ZOH of 1/(tau s + 1) for a held step: 2 (1 - e^{-t/tau}) at every sample
    assert_allclose(out, 2.0 * (1.0 - np.exp(-t / tau)), rtol=1e-12, atol=1e-15)


def test_filter_passthrough_and_series_identity():
    filt = SlipFilter(0.0)
    filt.update(0.0, 1.0)
    assert filt.update(0.001, -3.0) == -3.0
    t = np.cumsum(np.random.default_rng(2).uniform(1e-3, 2e-3, 500))
    u = np.sin(t * 20.0)
    loop = SlipFilter(0.02)
    expected = [loop.update(t[k] - t[k - 1] if k else 0.0, u[k]) for k in range(t.size)]
    assert_allclose(lowpass_series(t, u, 0.02), expected, rtol=0, atol=0)  # same float ops


def test_filter_rejects_bad_config_and_dt():
    with pytest.raises(InputError):
        SlipFilter(-1.0)
    filt = SlipFilter(0.1)
    filt.update(0.0, 1.0)
    for dt in (0.0, -1e-3, math.nan):
        with pytest.raises(InputError):
            filt.update(dt, 1.0)
    assert filt.value == 1.0
