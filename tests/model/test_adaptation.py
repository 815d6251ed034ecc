"""Online adaptation: the scaling of μ, the adaptive estimator's guards and bounds.

The scaling of μ is checked against the friction law, and the adaptive estimator on data from
a known truth: the same model with μ (and the spline gain) changed by known factors, so the
right answer is known exactly. The recursive estimator itself: tests/model/test_parameter_filter.py.
"""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import ClutchEstimator, friction_coefficient, reference_torque
from clutch_ros.model.adaptation import (
    AdaptationSettings,
    AdaptiveEstimator,
    fork_estimator,
    scaled_params,
)
from clutch_ros.model.errors import ModelError

W10 = 10 * 2 * math.pi / 60  # 10 rpm [rad/s]


def _pressure(t):
    """Return the test pressure [Pa] at ``t`` [s]: steps and ramps between 8 and 35 bar."""
    levels = [10e5, 25e5, 15e5, 35e5, 8e5, 30e5, 20e5]
    k = int(t // 5.0) % len(levels)
    nxt = levels[(k + 1) % len(levels)]
    into = t % 5.0
    return levels[k] if into < 3.0 else levels[k] + (nxt - levels[k]) * (into - 3.0) / 2.0


def _truth_run(params, duration=40.0, dt=0.01, noise=1.5, seed=0, slip=W10):
    """Return stamps [s], pressures [Pa], temperatures [°C], slips, measured torque [N m]."""
    rng = np.random.default_rng(seed)
    truth = ClutchEstimator(params)
    t = np.arange(0.0, duration, dt)
    p = np.array([_pressure(x) for x in t])
    temp = 35.0 + 10.0 * t / duration
    meas = np.array([truth.update(ti, pi, te, slip).modelled_torque
                     for ti, pi, te in zip(t, p, temp)]) + noise * rng.standard_normal(t.size)
    return t, p, temp, np.full(t.size, slip), meas


def _run(ae, data, drop_after=None):
    out = []
    for ti, pi, te, w, m in zip(*data):
        if drop_after is not None and ti >= drop_after:
            m = math.nan
        out.append(ae.update(ti, pi, te, w, m))
    return out


# -- μ scaling --------------------------------------------------------------------------------

@pytest.mark.parametrize("scale", [0.5, 0.93, 1.0, 1.37, 2.0])
def test_scaled_params_multiply_mu_exactly(flexiforce, scale):
    """μ (floor included) and the Eq. 1 torque are multiplied by the scale, nothing else."""
    q = scaled_params(flexiforce, scale)
    temp = np.array([-400.0, 35.0, 80.0, 150.0, 600.0])  # ±600 °C reach the μ_min floor
    p, w = np.array([0.0, 10e5, 20e5, 40e5, 5e5]), np.array([0.0, 0.3, W10, 3.0, -W10])
    # one multiplication more than the base: equal to 1 ulp-ish, allow 1e-13
    assert_allclose(friction_coefficient(q, temp, p, w),
                    scale * friction_coefficient(flexiforce, temp, p, w), rtol=1e-13)
    assert_allclose(reference_torque(q, p, temp, w),
                    scale * reference_torque(flexiforce, p, temp, w), rtol=1e-13)
    assert q.pack == flexiforce.pack and q.spline == flexiforce.spline


def test_scaled_params_gain_only_for_gain_laws(flexiforce, truth):
    assert scaled_params(flexiforce, 1.0, 0.5).spline.gain == 0.5 * flexiforce.spline.gain
    assert scaled_params(truth, 1.0, 0.5).spline == truth.spline  # coulomb has no gain
    with pytest.raises(ModelError):
        scaled_params(flexiforce, 0.0)
    with pytest.raises(ModelError):
        scaled_params(flexiforce, math.nan)


def test_settings_reject_bad_values():
    for bad in ({"forgetting_time": 0.0}, {"scale_min": 1.5}, {"scale_max": 0.9},
                {"measurement_std": -1.0}, {"settle_time": math.nan}):
        with pytest.raises(ModelError, match=next(iter(bad))):
            AdaptationSettings(**bad)


# -- the adaptive estimator on a known truth --------------------------------------------------

def test_recovers_a_known_friction_scale(flexiforce):
    """Truth = the model with μ x 1.2: the scale converges to 1.2 and the estimate follows."""
    data = _truth_run(scaled_params(flexiforce, 1.2))
    ae = AdaptiveEstimator(flexiforce)
    res = _run(ae, data)
    last = res[-1].adaptation
    # same model structure, 1.5 N m noise: the estimate is unbiased; allow 3e-3
    assert abs(ae.friction_scale - 1.2) < 3e-3
    assert abs(last.friction_scale - 1.2) < 5e-3  # applied in 0.2 % steps
    assert 0.0 < last.friction_scale_std < 0.01
    tail = slice(len(res) // 2, None)
    modelled = np.array([r.estimate.modelled_torque for r in res])[tail]
    # within 1 % of the truth's torque (the noise is 1.5 N m on 200-1200 N m)
    assert np.sqrt(np.mean((modelled - data[4][tail]) ** 2)) < 0.01 * np.abs(data[4][tail]).max()
    assert ae.counts["adapting"] > 0.3 * len(res)


def test_recovers_the_spline_gain_where_identifiable(flexiforce):
    """Truth: μ x 1.1 and κ x 0.5 (ff_t); the gain adapts from the transients."""
    data = _truth_run(scaled_params(flexiforce, 1.1, 0.5), noise=0.5)
    ae = AdaptiveEstimator(flexiforce, AdaptationSettings(spline_gain=True))
    _run(ae, data)
    assert abs(ae.friction_scale - 1.1) < 0.01
    assert abs(ae.spline_gain_scale - 0.5) < 0.1
    assert ae.status.spline_gain_scale_std > 0.0


def test_spline_gain_not_adapted_for_a_law_without_gain(truth):
    ae = AdaptiveEstimator(truth, AdaptationSettings(spline_gain=True))
    _run(ae, _truth_run(scaled_params(truth, 1.1), duration=10.0))
    assert ae.spline_gain_scale == 1.0 and ae.status.spline_gain_scale_std == 0.0
    assert abs(ae.friction_scale - 1.1) < 0.01


def test_scale_is_bounded(flexiforce):
    """A truth beyond the bound (x 2.3, plausible up to 2 x 1.25) pins the scale at 2."""
    ae = AdaptiveEstimator(flexiforce)
    _run(ae, _truth_run(scaled_params(flexiforce, 2.3), duration=15.0))
    assert ae.friction_scale == 2.0


def test_dropout_freezes_and_the_estimate_goes_on(flexiforce):
    """Measurement lost half way: frozen, scale kept, estimate as a frozen model's, counted."""
    data = _truth_run(scaled_params(flexiforce, 1.15))
    ae = AdaptiveEstimator(flexiforce, AdaptationSettings(apply_interval=0.0))
    res, frozen, replay = [], None, []
    for t, p, te, w, m in zip(*data):
        if t >= 20.0:
            if frozen is None:  # a plain estimator in the same state, with the same params
                frozen = fork_estimator(ae.estimator)
            replay.append(frozen.update(t, p, te, w).modelled_torque)
            m = math.nan
        res.append(ae.update(t, p, te, w, m))
    after = [r for r in res if r.estimate.stamp >= 20.0]
    grace = ae.settings.dropout_grace  # a late frame pauses, a longer gap freezes
    assert not any(r.adaptation.adapting for r in after)
    assert all(r.adaptation.state == "paused" for r in after
               if r.estimate.stamp <= 20.0 + grace)
    frozen = [r for r in after if r.estimate.stamp > 20.0 + grace + 1e-9]
    assert all(r.adaptation.state == "frozen" for r in frozen)
    assert "dropped out" in frozen[0].adaptation.reason
    scales = {r.adaptation.friction_scale for r in after}
    assert len(scales) == 1 and abs(scales.pop() - 1.15) < 5e-3
    assert ae.counts["dropouts"] == 1
    got = np.array([r.estimate.modelled_torque for r in after])
    assert np.isfinite(got).all()
    # the same computation on the same state: equal to the last bit, allow 1e-12
    assert_allclose(got, replay, rtol=1e-12, atol=0.0)


def test_implausible_measurement_freezes_then_recovers(flexiforce):
    data = list(_truth_run(scaled_params(flexiforce, 1.1), duration=30.0))
    bad = (data[0] >= 12.0) & (data[0] < 14.0)
    data[4] = np.where(bad, -3.0 * data[4], data[4])  # wrong sign and size (wiring fault)
    ae = AdaptiveEstimator(flexiforce)
    res = _run(ae, data)
    during = [r.adaptation for r, b in zip(res, bad) if b]
    assert any(a.state == "frozen" and "implausible" in a.reason for a in during)
    assert not any(a.adapting for a in during)
    assert ae.counts["implausible"] >= 1
    assert abs(ae.friction_scale - 1.1) < 5e-3  # learned values survived the fault
    assert res[-1].adaptation.state in ("adapting", "paused")


def test_waits_without_measurement_and_is_off_when_disabled(flexiforce):
    data = _truth_run(flexiforce, duration=5.0)
    data = (*data[:4], np.full(data[0].size, np.nan))
    ae = AdaptiveEstimator(flexiforce)
    assert {r.adaptation.state for r in _run(ae, data)} == {"waiting"}
    off = AdaptiveEstimator(flexiforce, AdaptationSettings(enabled=False))
    res = _run(off, _truth_run(scaled_params(flexiforce, 1.2), duration=5.0))
    assert {r.adaptation.state for r in res} == {"off"} and off.friction_scale == 1.0


def test_low_slip_pauses(flexiforce):
    """Near zero slip static friction and noise dominate: no adaptation."""
    data = _truth_run(scaled_params(flexiforce, 1.2), duration=10.0, slip=0.05)
    ae = AdaptiveEstimator(flexiforce)
    res = _run(ae, data)
    assert ae.friction_scale == 1.0
    assert any("slip below" in r.adaptation.reason for r in res)


def test_saved_scale_restarts_where_it_ended(flexiforce):
    ae = AdaptiveEstimator(flexiforce, friction_scale=1.3)
    assert ae.friction_scale == 1.3
    assert_allclose(ae.adapted_params().friction.mu_ref, 1.3 * flexiforce.friction.mu_ref)
