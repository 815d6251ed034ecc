"""Metrics: accuracy ratios and flags, RMSE, the ±10 % band, Eq. 3 with its band, hysteresis."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    InputError,
    accuracy_summary,
    cross_correlation,
    hysteresis_width,
    overshoot,
    request_accuracy,
    rmse,
    torque_accuracy,
    undershoot,
    within_band,
)


def test_accuracy_ratios_and_flags():
    acc = torque_accuracy([110.0, 90.0, 5.0, math.nan, 0.5], [100.0, 100.0, 0.5, 100.0, 100.0])
    assert_allclose(acc, [1.1, 0.9, math.nan, math.nan, 0.005], rtol=1e-15)  # |modelled|<1: NaN
    assert_allclose(request_accuracy([1200.0], [1000.0]), [1.2], rtol=1e-15)
    assert list(overshoot([1.11, 1.1, math.nan, 0.5])) == [True, False, False, False]
    assert list(undershoot([0.89, 0.9, math.nan, 1.5])) == [True, False, False, False]


def test_rmse_closed_form():
    assert rmse([1.0, 2.0, 3.0], [1.0, 0.0, 6.0]) == math.sqrt((0 + 4 + 9) / 3)
    assert rmse([1.0, math.nan], [3.0, 1.0]) == 2.0  # NaN pairs dropped
    assert math.isnan(rmse([math.nan], [1.0]))


def test_within_band_counts_only_above_threshold():
    measured = np.array([1000.0, 1000.0, 1000.0, 1000.0, 10.0, 10.0])
    modelled = np.array([1000.0, 1050.0, 1200.0, 850.0, 100.0, 100.0])
    # the 10 N m samples are below 5 % of 1000 and do not count: 2 of 4 inside [0.9, 1.1]
    assert within_band(measured, modelled) == 0.5
    summary = accuracy_summary(measured, modelled, reference=measured)
    assert summary["within_10pct"] == 0.5 and summary["reference_rmse_nm"] == 0.0
    assert_allclose([summary["max_accuracy"], summary["min_accuracy"]],
                    [1000 / 850, 1000 / 1200], rtol=1e-15)
    assert summary["samples"] == 6


def test_summary_in_blocks_equals_the_whole_array_formulas():
    """Several blocks, NaNs, tiny models, a mask: the figures of whole-array numpy formulas."""
    from clutch_ros.model.metrics import SUMMARY_BLOCK

    rng = np.random.default_rng(7)
    n = 3 * SUMMARY_BLOCK + 123
    measured = rng.normal(600.0, 300.0, n)
    modelled = measured * rng.normal(1.0, 0.08, n)
    reference = measured * rng.normal(1.02, 0.15, n)
    measured[rng.random(n) < 0.01] = math.nan
    modelled[rng.random(n) < 0.01] = 0.1  # below min_torque: no accuracy there
    keep = rng.random(n) < 0.9
    got = accuracy_summary(measured, modelled, reference, where=keep)
    m, mod, ref = measured[keep], modelled[keep], reference[keep]
    above = np.isfinite(m) & (np.abs(m) >= 0.05 * np.nanmax(np.abs(m)))  # the counted samples

    def oracle(model):  # the whole-array formulas, written out here
        acc = m / np.where(np.abs(model) >= 1.0, model, np.nan)
        with np.errstate(invalid="ignore"):
            inside = above & (acc >= 0.9) & (acc <= 1.1)
        err = (m - model)[np.isfinite(m - model)]
        return (np.sqrt(np.mean(err * err)), inside.sum() / above.sum(),
                acc[above & np.isfinite(acc)])

    rms, within, acc = oracle(mod)
    ref_rms, ref_within, _ = oracle(ref)
    assert got["samples"] == int(keep.sum())
    # sums of squares added per block instead of pairwise over the whole array: rounding only
    assert_allclose([got["rmse_nm"], got["reference_rmse_nm"]], [rms, ref_rms], rtol=1e-12)
    assert_allclose(got["rmse_nm"], rmse(m, mod), rtol=1e-12)
    assert got["within_10pct"] == within and within_band(m, mod) == within  # counts: exact
    assert got["reference_within_10pct"] == ref_within
    assert 0.7 < got["within_10pct"] < 0.9 and got["reference_within_10pct"] < 0.6
    assert got["max_accuracy"] == acc.max() and got["min_accuracy"] == acc.min()
    none = accuracy_summary(np.full(10, math.nan), np.ones(10))
    assert math.isnan(none["rmse_nm"]) and math.isnan(none["within_10pct"])
    assert math.isnan(none["max_accuracy"]) and math.isnan(none["reference_rmse_nm"])


def test_cross_correlation_formula_and_band():
    rng = np.random.default_rng(4)
    n = 4000
    u = rng.normal(0.0, 2.0, n)
    eps = rng.normal(0.0, 0.5, n)
    cc = cross_correlation(eps, u, max_lag=20)
    e0, u0 = eps - eps.mean(), u - u.mean()
    assert_allclose(cc.r[cc.lags == 3], np.dot(e0[3:], u0[:-3]) / n, rtol=1e-12)  # Eq. 3
    assert_allclose(cc.r[cc.lags == -2], np.dot(e0[:-2], u0[2:]) / n, rtol=1e-12)
    assert_allclose(cc.band, 2.5758 * e0.std() * u0.std() / math.sqrt(n), rtol=1e-4)  # 99 %
    assert cc.outside <= 3 / 41  # independent: ~1 % of lags outside, allow a few
    # a residual that contains the input delayed by 5 samples is caught at lag 5
    leak = eps.copy()
    leak[5:] += 0.3 * u[:-5]
    cc = cross_correlation(leak, u, max_lag=20)
    assert cc.lags[np.argmax(np.abs(cc.r))] == 5 and abs(cc.r[cc.lags == 5][0]) > 5 * cc.band
    with pytest.raises(InputError):
        cross_correlation(eps, u[:-1])


def test_hysteresis_width_on_a_synthetic_loop():
    p = np.concatenate([np.linspace(0, 40e5, 101), np.linspace(40e5, 0, 101)[1:]])
    torque = p * 3e-4
    torque[101:] *= 1.1  # 10 % more torque on the way down
    assert_allclose(hysteresis_width(p, torque, 20e5), 0.1 * 20e5 * 3e-4, rtol=1e-12)
    with pytest.raises(InputError):
        hysteresis_width(p, torque, 50e5)


def test_longest_run_measures_the_longest_true_stretch():
    from clutch_ros.model.metrics import longest_run

    t = np.arange(10) * 0.1  # [s]
    flags = [0, 1, 1, 0, 1, 1, 1, 1, 0, 1]
    # Stretches: 0.1..0.3 (0.2 s), 0.4..0.8 (0.4 s), 0.9..end (0 s): exact by construction.
    np.testing.assert_allclose(longest_run(flags, t), 0.4, rtol=1e-12)
    assert longest_run([0, 0, 0], t[:3]) == 0.0
    np.testing.assert_allclose(longest_run([1, 1, 1], t[:3]), 0.2, rtol=1e-12)
