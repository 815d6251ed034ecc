"""The adaptation's recursive estimator against closed forms, and its bounds.

The filter is checked against batch least squares (the closed form it must reproduce), against
exponentially weighted least squares with forgetting, and on adversarial data (bounds,
symmetric positive semi-definite covariance, non-finite input ignored).
"""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from clutch_ros.model.parameter_filter import ParameterFilter


def test_filter_equals_batch_least_squares_with_prior():
    """Without forgetting, RLS is batch weighted least squares with the prior as data."""
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(200, 2)) * [800.0, 50.0]
    theta_true = np.array([1.13, 0.7])
    y = phi @ theta_true + rng.normal(scale=5.0, size=200)
    r = 25.0
    prior_mean, prior_std = np.array([1.0, 1.0]), np.array([0.3, 0.5])
    f = ParameterFilter(prior_mean, prior_std, [-10, -10], [10, 10])
    for row, yi in zip(phi, y):
        f.update(row, yi, r, 1.0)
    info = np.diag(1 / prior_std**2) + phi.T @ phi / r
    cov = np.linalg.inv(info)
    mean = cov @ (prior_mean / prior_std**2 + phi.T @ y / r)
    # same arithmetic in another order: agreement to ~1e-12 relative, allow 1e-9
    assert_allclose(f.theta, mean, rtol=1e-9)
    assert_allclose(f.covariance, cov, rtol=1e-7, atol=1e-15)
    assert_allclose(f.std, np.sqrt(np.diag(cov)), rtol=1e-7)


def test_forgetting_weights_old_data_exponentially():
    """With forgetting λ, P⁻¹_n = λ P⁻¹_{n-1} + φφᵀ/R: exponentially weighted least squares."""
    rng = np.random.default_rng(2)
    n, lam, r = 300, 0.98, 4.0
    phi = np.column_stack([rng.uniform(100, 900, n), np.zeros(n)])
    y = phi[:, 0] * np.where(np.arange(n) < 150, 1.2, 0.9) + rng.normal(scale=2.0, size=n)
    f = ParameterFilter([1.0, 1.0], [1e3, 1.0], [-1e6, -1e6], [1e6, 1e6])  # cap never hit
    for row, yi in zip(phi, y):
        f.update(row, yi, r, lam, (True, False))
    w = lam ** np.arange(n - 1, -1, -1)
    info = lam**n / 1e6 + np.sum(w * phi[:, 0] ** 2) / r
    mean = (lam**n * 1.0 / 1e6 + np.sum(w * phi[:, 0] * y) / r) / info
    assert_allclose(f.theta[0], mean, rtol=1e-9)  # float rounding only
    assert_allclose(f.P[0][0], 1.0 / info, rtol=1e-9)
    assert f.theta[1] == 1.0 and f.P[1][1] == 1.0  # the inactive parameter never moved


def test_variance_never_exceeds_the_prior():
    """No wind-up: forgetting without information leaves the variance at the prior."""
    f = ParameterFilter([1.0, 1.0], [0.2, 0.5], [0.5, 0.2], [2.0, 5.0])
    for _ in range(1000):
        f.update((1e-9, 0.0), 1e-9, 100.0, 0.5)
    assert f.P[0][0] <= 0.2**2 * (1 + 1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e3, 1e3), st.floats(-1e5, 1e5),
                          st.floats(1e-3, 1e4), st.floats(0.5, 1.0), st.booleans(),
                          st.booleans()), min_size=1, max_size=60))
def test_filter_stays_bounded_and_positive_semidefinite(rows):
    """Adversarial data: θ within its bounds, P symmetric PSD, std finite."""
    f = ParameterFilter([1.0, 1.0], [0.2, 0.5], [0.5, 0.2], [2.0, 5.0])
    for h0, h1, y, r, lam, a0, a1 in rows:
        f.update((h0, h1), y, r, lam, (a0, a1))
        assert 0.5 <= f.theta[0] <= 2.0 and 0.2 <= f.theta[1] <= 5.0
        cov = f.covariance
        assert cov[0, 1] == cov[1, 0]
        assert np.linalg.eigvalsh(cov).min() >= -1e-12 * max(1.0, np.abs(cov).max())
        assert all(math.isfinite(v) for v in f.std)


def test_filter_ignores_non_finite_input():
    f = ParameterFilter([1.0, 1.0], [0.2, 0.5], [0.5, 0.2], [2.0, 5.0])
    before = (list(f.theta), f.covariance.copy())
    assert math.isnan(f.update((math.nan, 0.0), 1.0, 1.0))
    assert math.isnan(f.update((1.0, 0.0), math.inf, 1.0))
    assert f.theta == before[0] and (f.covariance == before[1]).all()
