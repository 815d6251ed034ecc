"""The recent measured offset of the torque band (clutch_ros.model.recent_error)."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import norm

from clutch_ros.model.errors import ModelError
from clutch_ros.model.recent_error import central_half_width, central_half_widths
from clutch_ros.model.uncertainty import Z95, ErrorModel, TorqueStd, fit_error_model, torque_std


def _mass(h, mean, sd):
    """Mass of N(mean, sd^2) in [-h, h] (scipy's normal, independent of the module)."""
    return norm.cdf(h, mean, sd) - norm.cdf(-h, mean, sd)


@pytest.mark.parametrize("mean, sd", [(0.3, 1.0), (-2.0, 1.0), (5.0, 0.5), (1e-9, 3.0),
                                      (100.0, 2.0)])
def test_the_half_width_holds_95_percent_of_the_predicted_normal(mean, sd):
    h = central_half_width(mean, sd)
    np.testing.assert_allclose(_mass(h, mean, sd), 0.95, atol=1e-12)  # Newton to 1e-13 h
    # the vectorised one (the fit's calibration) is the same iteration
    np.testing.assert_allclose(central_half_widths(np.array([mean]), np.array([sd])), h,
                               rtol=1e-13)  # rounding of erf in numpy vs math only


def test_the_half_width_has_its_two_closed_forms():
    # no offset: the normal quantile, exactly
    assert central_half_width(0.0, 2.0) == Z95 * 2.0
    # a large offset: the far tail is nil (Phi(-21) ~ 1e-98), so h = |mean| + z_0.95 sd
    np.testing.assert_allclose(central_half_width(-20.0, 2.0), 20.0 + 2.0 * norm.ppf(0.95),
                               rtol=1e-13)  # to the Newton tolerance
    # and it is monotone between: never below the zero-offset width, never beyond |m| + 1.96 sd
    for mean in (0.1, 1.0, 3.0):
        h = central_half_width(mean, 1.0)
        assert Z95 < h < mean + Z95


def test_the_offset_sets_the_band_in_closed_form():
    """The band of sigma = base = 2 N m, a held residual of 4 N m, dt = both time constants."""
    model = ErrorModel(noise=0.0, base=2.0, rel=0.0, rate_time=0.0, stick_rel=0.0,
                       rate_slip=0.0, recent_weight=0.5, recent_time_constant=0.1,
                       recent_scale=1.5, recent_mean_weight=1.0, recent_mean_time_constant=0.1)
    n = 8
    t = np.arange(n) * 0.1
    modelled = np.full(n, 100.0)
    std = torque_std(model, t, modelled, np.ones(n), modelled + 4.0)
    # M starts at 0 and E at 1 (the first residual only anchors the filters' time), then each
    # moves half way per sample: M_k = 4 (1 - 0.5^(k-1)) from k = 1; E follows the innovation
    # z = (4 - M) / 2 of the sample before
    m = np.array([0.0] + [4.0 * (1.0 - 0.5 ** (k - 1)) for k in range(1, n)])
    e = np.ones(n)
    for k in range(2, n):
        e[k] = e[k - 1] + 0.5 * (((4.0 - m[k - 1]) / 2.0) ** 2 - e[k - 1])
    sd = 1.5 * 2.0 * np.sqrt(0.5 + 0.5 * e)
    want = [brentq(lambda h, a=a, s=s: _mass(h, a, s) - 0.95, 0.0, a + 10.0 * s) / Z95
            if a else s for a, s in zip(m, sd)]
    np.testing.assert_allclose(std, want, rtol=1e-10)  # brentq's default xtol 2e-12
    # the published std is no narrower than the offset's: the band is beyond the offset
    assert np.all(Z95 * std[2:] > m[2:])
    # a gap above max_gap: both back to the prior (M 0, E 1), the band of sigma alone
    live = TorqueStd(model)
    for i in range(n):
        live.update(t[i], 100.0, 1.0, 104.0)
    np.testing.assert_allclose(live.update(t[-1] + 1.0, 100.0, 1.0, 104.0), 3.0, rtol=1e-14)
    # without a sensor: no offset, recent_scale * sigma throughout
    np.testing.assert_allclose(torque_std(model, t, modelled, np.ones(n)), 3.0, rtol=1e-14)
    with pytest.raises(ModelError, match="recent_mean_weight must be in"):
        ErrorModel(recent_mean_weight=1.5)


def _held_run(seed, hold, n=20000, dt=0.01):
    """Return a run whose error is an offset held ``hold`` samples (std 10 N m), noise 1 N m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    modelled = np.full(n, 500.0)
    offset = np.repeat(rng.normal(0.0, 10.0, n // hold + 1), hold)[:n]
    return t, modelled, modelled + offset + rng.normal(0.0, 1.0, n), np.ones(n)


def test_a_long_held_offset_is_not_covered_with_room_to_spare():
    """Fit on 2 s holds; on 10 s holds the band of E alone covers ~98 %, this one ~92 %."""
    t, modelled, measured, slip = _held_run(1, 200)
    model = fit_error_model(t, modelled, measured, slip)
    old = fit_error_model(t, modelled, measured, slip,
                          ErrorModel(recent_time_constant=1.0, recent_mean_time_constant=0.0))
    assert old.recent_mean_weight == 0.0
    assert model.recent_mean_weight > 0.8, model  # a held offset: the last one predicts it
    # the static part is the same fit with or without the recent offset
    assert (model.base, model.rel, model.noise) == (old.base, old.rel, old.noise)
    fractions = {}
    for hold in (200, 1000):
        t2, m2, y2, s2 = _held_run(2, hold)
        for name, mod in (("new", model), ("old", old)):
            std = torque_std(mod, t2, m2, s2, y2)
            fractions[name, hold] = float(np.mean(np.abs(y2 - m2) <= Z95 * std))
    # the same holds as the fit: both near 95 % (20,000 samples, ~100 holds: +-2 points)
    assert 0.93 <= fractions["new", 200] <= 0.97, fractions
    assert 0.93 <= fractions["old", 200] <= 0.97, fractions
    # 10 s holds (20 of them): the band of E alone is 1.96 x the held offset, this one just
    # beyond it
    assert fractions["old", 1000] > 0.975, fractions
    assert 0.90 <= fractions["new", 1000] <= 0.96, fractions


def test_the_node_and_the_fit_compute_the_same_predictive():
    t, modelled, measured, slip = _held_run(3, 150, n=3000)
    model = fit_error_model(t, modelled, measured, slip)
    live = TorqueStd(model)
    for i in range(len(t)):
        std = live.update(t[i], modelled[i], slip[i], measured[i])
        offset, spread = live.predictive
        # the published std is the central interval of the predictive, in closed form at 0
        want = spread if offset == 0.0 else central_half_width(offset, spread) / Z95
        assert std == want
    assert math.isfinite(std)
