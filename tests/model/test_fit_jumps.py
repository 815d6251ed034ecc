"""The fit's Jacobian across residual jumps (clutch_ros/model/fd_jacobian.py) on closed forms.

The whole fit on the golden runs, with a 1e-9 change of the model: tests/offline/
test_fit_robust.py.
"""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from clutch_ros.model.fd_jacobian import JacobianOf, jump_robust_jacobian


class _Smooth:
    """f(z) = A z + c z² (elementwise, first three rows), J = A + diag(2 c z); bounds ±1."""

    def __init__(self):
        self.a = np.array([[2.0, -1.0, 0.5], [0.0, 3.0, 1.0], [1.0, 1.0, 1.0], [4.0, 0.0, -2.0]])
        self.c = np.array([0.5, -1.0, 2.0])
        self.lower = np.array([-1.0, -1.0, -1.0])
        self.upper = np.array([1.0, 1.0, 1.0])

    def __call__(self, z):
        z = np.asarray(z, dtype=float)
        return self.a @ z + np.concatenate([self.c * z * z, [0.0]])

    def jacobian(self, z):
        j = self.a.copy()
        j[:3, :3] += np.diag(2.0 * self.c * z)
        return j


class _Jumping(_Smooth):
    """_Smooth plus a jump of 100 in row 3 where z[0] + z[2] crosses ``edge``."""

    edge = 0.0

    def __call__(self, z):
        f = super().__call__(z)
        f[3] += 100.0 if z[0] + z[2] > self.edge else 0.0
        return f


def test_smooth_residuals_get_the_central_difference():
    problem, z = _Smooth(), np.array([0.3, 0.2, -0.4])
    jac = jump_robust_jacobian(problem, z, 1e-3)
    assert_allclose(jac, problem.jacobian(z), rtol=1e-9, atol=1e-9)  # exact for a quadratic
    with ThreadPoolExecutor(2) as pool:  # evaluated two at a time: the same bits
        assert_array_equal(jump_robust_jacobian(problem, z, 1e-3, map_=pool.map), jac)


@pytest.mark.parametrize("offset", [-4e-4, -1e-12, 0.0, 1e-12, 4e-4])
def test_a_jump_within_the_step_leaves_the_slope_of_the_points_side(offset):
    """Either side of the edge, however close: the jump row gets its smooth slope, not 1e5."""
    problem = _Jumping()
    z = np.array([0.3, 0.2, -0.3 + offset])  # z[0] + z[2] = offset: the edge within h = 1e-3
    jac = jump_robust_jacobian(problem, z, 1e-3)
    assert_allclose(jac, problem.jacobian(z), rtol=1e-9, atol=1e-9)


def test_a_parameter_at_its_bound_uses_the_one_side_there():
    problem = _Smooth()
    z = np.array([0.3, 1.0 - 1e-12, -0.4])  # z[1] a sliver below its upper bound
    jac = jump_robust_jacobian(problem, z, 1e-3)
    expected = problem.jacobian(z)
    expected[1, 1] = problem.a[1, 1] + 2.0 * problem.c[1] * (1.0 - 0.5e-3)  # backward secant
    assert_allclose(jac, expected, rtol=1e-9, atol=1e-9)


def test_a_jump_beside_a_parameter_at_its_bound_is_caught_by_the_second_step():
    problem = _Jumping()
    z = np.array([1.0, 0.2, -1.0 + 1.5e-3])  # z[0] at its bound; the edge between z - h, z - 2h
    jac = jump_robust_jacobian(problem, z, 1e-3)
    expected = problem.jacobian(z)
    expected[0, 0] = problem.a[0, 0] + problem.c[0] * (2.0 - 1e-3)  # the secant over [z - h, z]
    assert_allclose(jac, expected, rtol=1e-9, atol=1e-9)


def test_the_solver_wrapper_reuses_the_last_value():
    problem = _Smooth()
    calls = []
    counted = lambda z: calls.append(1) or problem(z)  # noqa: E731
    counted.lower, counted.upper = problem.lower, problem.upper
    fun = JacobianOf(counted, 1e-3)
    z = np.array([0.1, 0.2, 0.3])
    fun(z)
    calls.clear()
    assert_allclose(fun.jacobian(z), problem.jacobian(z), rtol=1e-9, atol=1e-9)
    assert len(calls) == 6  # 2 n: f(z) came from the solver's own evaluation
