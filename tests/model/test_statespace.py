"""State space of Eqs. 11-26 and its exact ZOH discretisation."""

from decimal import Decimal, localcontext

import numpy as np
import pytest
import scipy.linalg
from numpy.testing import assert_allclose
from scipy.signal import cont2discrete

from clutch_ros.model import PackModel
from clutch_ros.model.discretisation import PackModes
from clutch_ros.model.statespace import (
    build_state_space,
    pack_discretize,
    spring_force_matrix,
    static_gain,
    zoh_discretize,
)
from tests.model.closed_forms import modal_phi


def thesis_eq24_25(m, k, c):
    """Eqs. 24-25 exactly as printed (N = 3)."""
    a = np.array([
        [0, 1, 0, 0, 0, 0],
        [-k / m, -c / m, k / m, c / m, 0, 0],
        [0, 0, 0, 1, 0, 0],
        [k / m, c / m, -2 * k / m, -2 * c / m, k / m, c / m],
        [0, 0, 0, 0, 0, 1],
        [0, 0, k / m, c / m, -2 * k / m, -2 * c / m],
    ])
    b = np.array([[0, 0], [1 / m, -1 / m], [0, 0], [0, -1 / m], [0, 0], [0, -1 / m]])
    return a, b


def test_n3_equals_thesis_matrices_with_lamellas_renumbered():
    m, k, c = 0.1, 4e8, 4e7
    a, b = build_state_space(3, m, k, c)
    a_t, b_t = thesis_eq24_25(m, k, c)
    # Eqs. 24-25 number the lamellas front-to-rear (F_act enters lamella 1); Eqs. 11-13 and
    # this module rear-to-front. Reversing the lamella order maps one onto the other exactly.
    order = np.array([4, 5, 2, 3, 0, 1])
    assert_allclose(a[np.ix_(order, order)], a_t, rtol=0, atol=0)
    assert_allclose(b[order, 0], b_t[:, 0], rtol=0, atol=0)
    assert_allclose(b[order, 1:].sum(axis=1), b_t[:, 1], rtol=0, atol=0)  # one F_f for all


def test_general_n_rows_follow_eqs_11_to_13():
    n, m, k, c = 5, 0.2, 3.0, 0.5
    a, b = build_state_space(n, m, k, c)
    z = np.arange(1.0, n + 1) ** 2  # arbitrary positions
    v = np.linspace(-1.0, 2.0, n)  # arbitrary velocities
    x = np.empty(2 * n)
    x[0::2], x[1::2] = z, v
    f_act, f_f = 7.0, np.linspace(0.1, 0.5, n)
    xdot = a @ x + b @ np.concatenate([[f_act], f_f])
    zz, vv = np.concatenate([[0.0], z]), np.concatenate([[0.0], v])
    for i in range(1, n + 1):  # Eqs. 11-13 generalised, written out
        acc = -k * (zz[i] - zz[i - 1]) - c * (vv[i] - vv[i - 1]) - f_f[i - 1]
        acc += k * (zz[i + 1] - zz[i]) + c * (vv[i + 1] - vv[i]) if i < n else f_act
        assert_allclose(xdot[2 * i - 2], v[i - 1], rtol=1e-15)
        assert_allclose(xdot[2 * i - 1], acc / m, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 8, 13])
def test_static_gain_is_series_springs(n):
    k = 4e8
    a, b = build_state_space(n, 0.1, k, 4e7)
    gain = static_gain(n, k)
    # equilibrium: A X + B = 0 (relative to the k/m = 4e9 entries)
    assert_allclose(a @ gain, -b, rtol=0, atol=1e-6 * np.abs(b).max())
    # series springs: z_n = n F / k under F_act; every spring carries F
    f = 15e3
    x = gain[:, 0] * f
    assert_allclose(x[0::2], np.arange(1, n + 1) * f / k, rtol=1e-15)
    assert_allclose(spring_force_matrix(n, k) @ x, np.full(n, f), rtol=1e-12)


def test_zoh_matches_cont2discrete_on_a_non_stiff_system():
    a, b = build_state_space(4, 1.0, 3.0, 0.4)
    c, d = np.eye(8), np.zeros((8, 5))
    for dt in (1e-3, 0.1, 2.0):
        phi, gamma = zoh_discretize(a, b, dt)
        phi_ref, gamma_ref, *_ = cont2discrete((a, b, c, d), dt, method="zoh")
        assert_allclose(phi, phi_ref, rtol=1e-12, atol=1e-14)  # same definition, rounding
        assert_allclose(gamma, gamma_ref, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2, 1.0])
def test_pack_discretisation_matches_cont2discrete(flexiforce, dt):
    pk = flexiforce.pack
    a, b = build_state_space(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    n = a.shape[0]
    phi_ref, gamma_ref, *_ = cont2discrete((a, b, np.eye(n), np.zeros((n, 9))), dt,
                                           method="zoh")
    phi, gamma = pack_discretize(a, b, static_gain(8, pk.lamella_stiffness), dt)
    # expm of this stiff matrix (|A dt| up to 1.6e9) is accurate to ~1e-8..4e-7 relative to
    # each column's scale for scipy's unbalanced expm (ours is ~10x better, see below)
    for mine, ref in ((phi, phi_ref), (gamma, gamma_ref)):
        scale = np.abs(ref).max(axis=0)
        assert_allclose(mine / scale, ref / scale, rtol=0, atol=1e-6)
    # the same matrices sit in PackModel's cache with transition="expm" (law none:
    # M = [Phi | Gamma(F, T, F_f)]); its default, the closed form, within the expm's error
    phi_q, gamma_q = pack_discretize(a, b, static_gain(8, pk.lamella_stiffness),
                                     PackModel(flexiforce).discretisation(dt).dt)
    scale = np.abs(phi_q).max(axis=0)
    for transition, tol in (("expm", 1e-12), ("auto", 2e-7)):  # rounding; expm's error
        model = PackModel(flexiforce.with_law("none"), transition=transition)
        entry = model.discretisation(dt)
        assert_allclose(entry.M[:, :n] / scale, phi_q / scale, rtol=0, atol=tol)
        assert_allclose(entry.M[:, n], gamma_q[:, 0], rtol=0,
                        atol=tol * np.abs(gamma_q[:, 0]).max())
        assert_allclose(entry.M[:, n + 2:], gamma_q[:, 1:], rtol=0,
                        atol=tol * np.abs(gamma_q[:, 1:]).max())


@pytest.mark.parametrize("dt", [1e-5, 1e-3, 0.05, 1.0])
def test_discretisation_against_closed_form(flexiforce, dt):
    pk = flexiforce.pack
    a, b = build_state_space(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    phi, _ = zoh_discretize(a, b, dt)
    exact = modal_phi(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping, dt)
    scale = np.abs(exact).max(axis=0)
    # balanced expm of the stiff matrix: observed <= 5e-8 of each column's scale
    assert_allclose(phi / scale, exact / scale, rtol=0, atol=2e-7)


def test_discrete_equilibrium_exact_and_stable_at_any_dt(flexiforce):
    pk = flexiforce.pack
    a, b = build_state_space(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    gain = static_gain(8, pk.lamella_stiffness)
    u = np.zeros(9)
    u[0], u[3] = 15e3, 200.0
    x_eq = gain @ u
    for dt in (1e-6, 1e-3, 0.5, 1e4):
        phi, gamma = pack_discretize(a, b, gain, dt)
        assert np.max(np.abs(np.linalg.eigvals(phi))) < 1.0  # stable for every dt
        # Gamma = (I - Phi) X_ss: the equilibrium is a fixed point to rounding
        # (velocities come out as ~1e-19 m/s instead of 0: rounding at the 3e-4 m scale)
        assert_allclose(phi @ x_eq + gamma @ u, x_eq, rtol=0, atol=1e-14 * np.abs(x_eq).max())


def test_exact_step_response_against_matrix_exponential(flexiforce):
    # x(t) = X F + e^{A t} (x0 - X F) for a held force: compare samples of 1 ms ZOH steps
    pk = flexiforce.pack
    a, b = build_state_space(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    gain = static_gain(8, pk.lamella_stiffness)
    u = np.zeros(9)
    u[0] = 15e3
    phi, gamma = pack_discretize(a, b, gain, 1e-3)
    x = np.zeros(16)
    for k in range(1, 301):
        x = phi @ x + gamma @ u
        if k % 50 == 0:
            ref = gain @ u + scipy.linalg.expm(a * k * 1e-3) @ (-gain @ u)
            # both are expm of the stiff matrix (|A t| up to 6e8 for the reference): agree to
            # ~3e-8 of the 0.3 mm compression; 1e-7 leaves margin, far below any physics
            assert_allclose(x[0::2], ref[0::2], rtol=0, atol=1e-7 * 3e-4)


# -- the closed-form transition (model/discretisation.py PackModes) -------------------------


@pytest.mark.parametrize("dt", [1e-5, 1e-3, 1.05e-3, 0.05, 1.0])
def test_closed_form_transition_equals_the_modal_reference(flexiforce, dt):
    pk = flexiforce.pack
    phi = PackModes(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping).transition(dt)
    exact = modal_phi(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping, dt)
    scale = np.abs(exact).max(axis=0)
    # two codings of the same formulas (Sylvester, two real roots): rounding only
    assert_allclose(phi / scale, exact / scale, rtol=0, atol=1e-12)
    a, b = build_state_space(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    expm_phi, _ = zoh_discretize(a, b, dt)
    # the balanced expm it replaces: within the expm's own error (test above, observed
    # <= 5e-8 of each column's scale)
    assert_allclose(expm_phi / scale, exact / scale, rtol=0, atol=2e-7)


@pytest.mark.parametrize("damping", [0.0, 0.4, 2.0 * (1 - 1e-9), 2.0, 2.0 * (1 + 1e-9), 30.0])
@pytest.mark.parametrize("n", [1, 3, 8])
def test_closed_form_transition_equals_expm_on_non_stiff_packs(n, damping):
    # undamped, underdamped, (nearly) critically damped and overdamped modes (for n = 1,
    # damping 2 is the double root); expm is accurate to ~1e-15 on these small matrices
    a, b = build_state_space(n, 1.0, 1.0, damping)
    modes = PackModes(n, 1.0, 1.0, damping)
    for dt in (1e-4, 0.3, 2.0, 25.0):
        expected = scipy.linalg.expm(a * dt)
        assert_allclose(modes.transition(dt), expected, rtol=1e-11, atol=1e-13)


def test_closed_form_transition_composes_and_keeps_the_equilibrium(flexiforce):
    pk = flexiforce.pack
    modes = PackModes(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    # semigroup: e^{A s} e^{A t} = e^{A (s + t)} (column scales as above)
    both = modes.transition(3e-4) @ modes.transition(7e-4)
    once = modes.transition(1e-3)
    scale = np.abs(once).max(axis=0)
    assert_allclose(both / scale, once / scale, rtol=0, atol=1e-12)
    # with Γ = (I − Φ) X_ss the equilibrium stays a fixed point (PackModel's use)
    gain = static_gain(8, pk.lamella_stiffness)
    u = np.zeros(9)
    u[0], u[3] = 15e3, 200.0
    x_eq = gain @ u
    for dt in (1e-6, 1e-3, 0.5, 1e4):
        phi = modes.transition(dt)
        assert np.max(np.abs(np.linalg.eigvals(phi))) < 1.0
        assert_allclose(phi @ x_eq + (np.eye(16) - phi) @ gain @ u, x_eq, rtol=0,
                        atol=1e-14 * np.abs(x_eq).max())


@pytest.mark.parametrize("dt", [1e-5, 1e-3, 1.0])
def test_closed_form_mode_blocks_against_60_digit_arithmetic(flexiforce, dt):
    # each mode's 2 x 2 exponential, Sylvester's formula in 60-digit decimal arithmetic from
    # the same roots' coefficients a, b: the float64 formulas lose no digits to cancellation
    pk = flexiforce.pack
    modes = PackModes(8, pk.lamella_mass, pk.lamella_stiffness, pk.lamella_damping)
    got = modes.block_entries(dt)
    for i in range(8):
        with localcontext() as ctx:
            ctx.prec = 60
            a, b = Decimal(modes._a[i]), Decimal(modes._b[i])
            s1 = (-b - (b * b - 4 * a).sqrt()) / 2
            s2 = a / s1
            e1, e2, d = (s1 * Decimal(dt)).exp(), (s2 * Decimal(dt)).exp(), s1 - s2
            exact = [(s1 * e2 - s2 * e1) / d, (e1 - e2) / d, -a * (e1 - e2) / d,
                     (s1 * e1 - s2 * e2) / d]
        for entry, want in zip(got, exact):
            assert_allclose(entry[i], float(want), rtol=4e-15, atol=0)
