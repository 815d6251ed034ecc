"""Finite-difference helpers of the fit (``clutch_ros.model.fit_data``) against closed forms."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal

from clutch_ros.model.fit_data import central_jacobian, conditioning


class _Quadratic:
    """f(z) = A z + c * z**2 (elementwise), so J = A + diag(2 c z), within bounds."""

    def __init__(self):
        self.a = np.array([[2.0, -1.0, 0.5], [0.0, 3.0, 1.0], [1.0, 1.0, 1.0], [4.0, 0.0, -2.0]])
        self.c = np.array([0.5, -1.0, 2.0])
        self.lower = np.array([-1.0, -1.0, -1.0])
        self.upper = np.array([1.0, 0.2005, 1.0])  # z[1] = 0.2 sits 5e-4 below its bound

    def __call__(self, z):
        z = np.asarray(z, dtype=float)
        return self.a @ z + np.concatenate([self.c * z * z, [0.0]])

    def jacobian(self, z):
        j = self.a.copy()
        j[:3, :3] += np.diag(2.0 * self.c * z)
        return j


def test_central_differences_are_exact_for_a_quadratic_even_at_a_bound():
    problem, z = _Quadratic(), np.array([0.3, 0.2, -0.4])
    jac = central_jacobian(problem, z, 1e-3)
    # the column at the bound uses [z - h, upper]: for a quadratic the secant slope there is
    # the derivative at the interval's midpoint, 0.19975 instead of 0.2
    expected = problem.jacobian(z)
    expected[1, 1] = problem.a[1, 1] + 2.0 * problem.c[1] * (0.2 - 1e-3 + 0.2005) / 2.0
    assert_allclose(jac, expected, rtol=1e-9, atol=1e-9)  # rounding of 2e-3-wide differences
    with ThreadPoolExecutor(2) as pool:  # evaluated two at a time: the same bits
        assert_array_equal(central_jacobian(problem, z, 1e-3, pool.map), jac)


def test_conditioning_of_the_normalised_jacobian():
    assert conditioning(np.eye(3)) == 1.0
    assert_allclose(conditioning(np.array([[1.0, 1.0], [1.0, 1.0 + 1e-6]])),
                    np.linalg.cond(np.array([[1.0, 1.0], [1.0, 1.0 + 1e-6]])) ** -1,
                    rtol=1e-3)  # near-parallel columns of equal norm
    assert conditioning(np.array([[1.0, 0.0], [2.0, 0.0]])) == 0.0  # a zero column
