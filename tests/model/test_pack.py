"""PackModel: closed forms (Eq. 1, series springs, step response), sampling, state handling."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    InputError,
    NonFiniteSample,
    PackModel,
    friction_coefficient,
    reference_torque,
    simulate,
    slip_sign,
)
from tests.model.closed_forms import step_response_positions

W10 = 10 * 2 * math.pi / 60  # 10 rpm [rad/s]


@pytest.fixture
def none_params(flexiforce):
    return flexiforce.with_law("none")


def test_reset_is_the_series_spring_equilibrium(none_params):
    pk = none_params.pack
    model = PackModel(none_params)
    model.reset(40e5, 35.0, W10)
    force = 40e5 * pk.piston_area
    n = np.arange(1, pk.lamella_count + 1)
    # z_n = n F / k, z_N = N F / k: series springs (exact up to one rounding)
    assert_allclose(model.positions, n * force / pk.lamella_stiffness, rtol=1e-15)
    sample = model.output(40e5, W10, 35.0)
    assert_allclose(sample.normal_force, force, rtol=1e-12)  # every spring carries F
    assert_allclose(sample.compression, pk.lamella_count * force / pk.lamella_stiffness,
                    rtol=1e-15)


def test_held_pressure_converges_to_eq1_and_series_springs(none_params):
    pk = none_params.pack
    t = np.arange(0.0, 5.0, 1e-3)  # 50 time constants of c/k = 0.1 s
    res = simulate(none_params, t, 40e5, W10, 35.0, initial_pressure=0.0)
    # converged: e^-50 ~ 2e-22 of the step is left, so only rounding remains
    assert_allclose(res.torque[-1], reference_torque(none_params, 40e5, 35.0, W10),
                    rtol=1e-12)
    assert_allclose(res.compression[-1],
                    pk.lamella_count * 40e5 * pk.piston_area / pk.lamella_stiffness,
                    rtol=1e-12)
    assert_allclose(res.pressure_difference[-1], 0.0, atol=1e-6)  # Pa, of 4e6 Pa


def test_step_response_against_closed_form(none_params):
    pk = none_params.pack
    dt = 1e-3
    t = np.arange(0.0, 0.6 + dt / 2, dt)
    res = simulate(none_params, t, 40e5, W10, 35.0, initial_pressure=0.0)
    z = step_response_positions(pk.lamella_count, pk.lamella_mass, pk.lamella_stiffness,
                                pk.lamella_damping, 40e5 * pk.piston_area, t[::50])
    # μ at the pack's own mean normal force k z_N / (N A), not at the input pressure
    p_eq = pk.lamella_stiffness * z[:, -1] / (pk.lamella_count * pk.piston_area)
    mu = friction_coefficient(none_params, 35.0, p_eq, W10)
    expected = 2 * mu * pk.effective_radius * pk.lamella_stiffness * z[:, -1] * slip_sign(
        none_params, W10)
    # expm accuracy on the stiff matrix: ~5e-8 of the final torque
    assert_allclose(res.torque[::50], expected, rtol=0, atol=2e-7 * expected[-1])
    # the torque time constant is c/k (all modes share the slow root -k/c to ~3e-6)
    tau = pk.lamella_damping / pk.lamella_stiffness
    # (read on the compression: μ rises a little while the pack is not yet fully loaded)
    final = pk.lamella_count * 40e5 * pk.piston_area / pk.lamella_stiffness
    assert_allclose(res.compression[int(round(tau / dt))] / final, 1 - math.exp(-1), rtol=1e-5)


def test_eq27_outputs_are_consistent(flexiforce):
    seq_t = np.arange(0.0, 1.5, 1e-3)
    press = np.where(seq_t > 0.2, 40e5, 0.0)
    res = simulate(flexiforce, seq_t, press, W10, 35.0)
    pk = flexiforce.pack
    eq27 = 2 * res.mu * pk.effective_radius * res.normal_force.sum(axis=1) * slip_sign(
        flexiforce, W10)
    assert_allclose(res.torque, eq27, rtol=1e-12, atol=1e-9)  # telescoped sum = k z_N
    assert_allclose(res.front_pressure, res.normal_force[:, -1] / pk.piston_area, rtol=1e-15)
    assert_allclose(res.rear_pressure, res.normal_force[:, 0] / pk.piston_area, rtol=1e-15)
    assert_allclose(res.pressure_difference, res.front_pressure - res.rear_pressure, rtol=1e-15)
    # compressing against ff_t spline friction: front carries more than rear (P_diff > 0),
    # the passive law's force bounded by the spline cone a (S_n + S_n+1), a ~ 0.005
    k = int(0.3 / 1e-3)
    assert 0.01 * 40e5 < res.pressure_difference[k] < 0.1 * 40e5


def test_slip_direction_sets_torque_sign(flexiforce):
    t = np.arange(0.0, 0.5, 1e-3)
    pos = simulate(flexiforce, t, 30e5, W10, 40.0)
    neg = simulate(flexiforce, t, 30e5, -W10, 40.0)
    assert_allclose(neg.torque, -pos.torque, rtol=1e-15)
    assert_allclose(neg.normal_force, pos.normal_force, rtol=1e-15)  # forces do not care
    still = simulate(flexiforce, t, 30e5, 0.0, 40.0)
    assert np.all(still.torque == 0.0)


def test_variable_dt_is_exact_for_held_inputs(none_params):
    # ZOH with a held input is exact, so any split of [0, 0.3 s] ends in the same state
    # (dts are whole 10 us: the cache quantisation, dt_resolution = 10 us, is then exact)
    rng = np.random.default_rng(7)
    steps = np.cumsum(rng.integers(5, 500, 400))
    steps = np.append(steps[steps < 30_000], 30_000)
    t_var = np.concatenate([[0.0], steps * 1e-5])
    t_fix = np.arange(301) * 1e-3
    runs = [simulate(none_params, t, 40e5, W10, 35.0, initial_pressure=0.0)
            for t in (t_var, t_fix, np.array([0.0, 0.3]))]
    # rounding of ~100-300 products of expm results: agree to ~1e-12
    assert_allclose(runs[0].positions[-1], runs[1].positions[-1], rtol=1e-9)
    assert_allclose(runs[0].positions[-1], runs[2].positions[-1], rtol=1e-9)


@pytest.mark.parametrize("law", ["none", "ff_t", "ff_v", "coulomb", "ff_t_printed",
                                 "ff_v_printed"])
def test_stable_with_huge_sample_times(flexiforce, law):
    params = flexiforce.with_law(law)
    model = PackModel(params)
    model.reset(0.0, 35.0, W10)
    ref = reference_torque(params, 40e5, 35.0, W10)
    for dt in (0.5, 10.0, 1e4, 1e4):
        s = model.step(dt, 40e5, W10, 35.0)
        assert np.all(np.isfinite(s.normal_force)) and 0.0 < s.torque <= 1.2 * ref
    if law in ("none", "ff_t_printed"):  # exact ZOH of pack + law: equilibrium after 1e4 s
        assert_allclose(s.torque, ref, rtol=1e-12)


def test_bad_input_rejected_and_state_untouched(flexiforce):
    model = PackModel(flexiforce)
    model.reset(20e5, 35.0, W10)
    model.step(1e-3, 30e5, W10, 35.0)
    before = model.state.work.copy()
    for args in ((1e-3, math.nan, W10, 35.0), (1e-3, 30e5, math.inf, 35.0),
                 (1e-3, 30e5, W10, -math.inf)):
        with pytest.raises(NonFiniteSample):
            model.step(*args)
    for dt in (0.0, -1e-3, math.nan, math.inf):
        with pytest.raises(InputError):
            model.step(dt, 30e5, W10, 35.0)
    assert np.array_equal(model.state.work, before)
    assert np.all(np.isfinite(model.step(1e-3, 30e5, W10, 35.0).normal_force))


def test_snapshot_restore_and_copy(truth):
    model = PackModel(truth)
    model.reset(0.0, 35.0, W10)
    for k in range(300):
        model.step(1e-3, k * 1e4, W10, 35.0)
    snap = model.state
    twin = model.copy()
    ref = [model.step(1e-3, 30e5 - k * 1e4, W10, 35.0).torque for k in range(200)]
    assert [twin.step(1e-3, 30e5 - k * 1e4, W10, 35.0).torque for k in range(200)] == ref
    model.restore(snap)
    assert [model.step(1e-3, 30e5 - k * 1e4, W10, 35.0).torque for k in range(200)] == ref
    other = PackModel(truth.replace(**{"clutch.lamella_count": 9}))
    with pytest.raises(InputError):
        other.restore(snap)


def test_set_params_keeps_state(flexiforce):
    model = PackModel(flexiforce)
    model.reset(0.0, 35.0, W10)
    for _ in range(150):
        model.step(1e-3, 40e5, W10, 35.0)
    z = model.positions
    torque = model.output(40e5, W10, 35.0).torque
    model.set_params(flexiforce.replace(**{"friction.mu_ref": 0.132}))  # +10 %
    assert np.array_equal(model.positions, z)
    assert_allclose(model.output(40e5, W10, 35.0).torque, 1.1 * torque, rtol=1e-12)
    model.set_params(flexiforce.replace(**{"clutch.lamella_count": 6}))  # new shape
    assert model.positions.shape == (6,)
    assert_allclose(model.positions[-1], 6 * 40e5 * 3.75e-3 / 4e8, rtol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 13])
def test_any_lamella_count(flexiforce, n):
    params = flexiforce.replace(**{"clutch.lamella_count": n})
    t = np.arange(0.0, 3.0, 2e-3)
    res = simulate(params, t, 40e5, W10, 35.0, initial_pressure=0.0)
    assert res.normal_force.shape == (t.size, n)
    # ff_t forces have decayed by e^-3 after 3 s: within 6 % of Eq. 1, never above it
    ref = reference_torque(params, 40e5, 35.0, W10)
    assert 0.94 * ref < res.torque[-1] <= ref


def test_negative_pressure_is_zero_force(none_params):
    model = PackModel(none_params)
    model.reset(-3e5)
    assert np.all(model.positions == 0.0)
    assert model.step(1e-3, -3e5, W10, 35.0).torque == 0.0


def test_spline_correction_is_the_quasi_static_pressure_loss(truth):
    # coulomb: ramp up, hold; the stuck pack keeps the loss. With velocities ~0 the springs
    # carry N F_act - sum_m m F_fm, i.e. Eq. 27 equals Eq. 1 at p - correction.
    t = np.arange(0.0, 8.0, 1e-3)
    press = np.interp(t, [0.0, 1.0, 4.0, 8.0], [0.0, 0.0, 40e5, 40e5])
    model = PackModel(truth)
    res = simulate(truth, t, press, W10, 35.0, model=model)
    corr = model.spline_correction()
    assert corr > 0.02 * 40e5  # compressing against stiction: a real loss
    mu = res.mu[-1]
    pk = truth.pack
    eq1_at_corrected = (2 * pk.effective_radius * mu * pk.lamella_count * pk.piston_area
                        * (40e5 - corr) * math.tanh(W10 / truth.friction.sign_speed))
    assert_allclose(res.torque[-1], eq1_at_corrected, rtol=1e-9)  # rounding of the sums


def test_discretisation_cache_evicts_least_recently_used(flexiforce):
    """A dt in use stays cached while rare dts come and go (cache of 2 entries)."""
    model = PackModel(flexiforce, cache_size=2)
    common = model.discretisation(1e-3)
    model.discretisation(2e-3)
    assert model.discretisation(1e-3) is common  # a hit: no new expm
    model.discretisation(3e-3)  # evicts 2 ms, the least recently used, not 1 ms
    assert model.discretisation(1e-3) is common
    assert sorted(model._cache) == [100, 300]  # keys in units of dt_resolution (10 µs)
    assert_allclose(common.M, PackModel(flexiforce).discretisation(1e-3).M, rtol=0, atol=0)


@pytest.mark.parametrize("law", ["ff_t", "coulomb"])
def test_new_friction_keeps_the_discretisation_cache_and_the_same_steps(flexiforce, law):
    """The adaptation's μ scale (friction only) keeps the cached ZOH and box matrices.

    They depend on the pack and the spline law only; a model whose cache is emptied after the
    change (everything recomputed) must step to the same bits. A new spline gain or pack
    changes the matrices: the cache is rebuilt then.
    """
    base = flexiforce.with_law(law)
    rng = np.random.default_rng(5)
    dts = 1e-3 + rng.uniform(-5e-5, 5e-5, 400)  # a jittery 1 kHz stamp: ~10 cache entries
    kept, rebuilt = PackModel(base), PackModel(base)
    for model in (kept, rebuilt):
        model.reset(20e5, 60.0, W10)
    out = {}
    for model in (kept, rebuilt):
        rows = []
        for k, dt in enumerate(dts):
            if k == 200:
                entry = model.discretisation(1e-3)
                model.set_params(base.replace(**{"friction.mu_ref": 1.07 * base.friction.mu_ref,
                                                 "friction.mu_min": 1.07 * base.friction.mu_min}))
                if model is kept:
                    assert model.discretisation(1e-3) is entry  # no new expm
                else:
                    model._cache.clear()
                    model._last_key = model._last_entry = None
            rows.append(model.step(float(dt), 20e5 + 1e5 * math.sin(k / 30), W10, 60.0).torque)
        out[id(model)] = np.array(rows)
    np.testing.assert_array_equal(out[id(kept)], out[id(rebuilt)])
    entry = kept.discretisation(1e-3)
    kept.set_params(base.replace(**{"clutch.lamella_damping": 2 * base.pack.lamella_damping}))
    assert kept.discretisation(1e-3) is not entry  # new pack: recomputed


@pytest.mark.parametrize("law", ["none", "coulomb", "ff_t", "ff_v", "ff_t_printed",
                                 "ff_v_printed"])
def test_closed_form_discretisation_steps_as_expm_did(flexiforce, law):
    """transition="auto" (closed-form e^{A dt}) against "expm" on a jittery 1 kHz stream.

    The closed form is exact to rounding, the balanced expm of the stiff matrix to ~5e-8 of
    each column's scale (tests/model/test_statespace.py); the equilibrium is exact in both
    (Γ = (I − Φ) X_ss), so the outputs differ only by the expm's error on the transients:
    observed 5e-11 of the largest torque and compression, 1e-9 of the largest normal force,
    3e-8 of the largest spline force (coulomb; the box solve amplifies, as in
    tests/model/test_kernel.py); held to 1e-9, 1e-8 and 1e-6 of them.
    """
    tolerance = {"torque": 1e-9, "compression": 1e-9, "normal_force": 1e-8,
                 "spline_force": 1e-6}
    params = flexiforce.with_law(law)
    auto, ref = PackModel(params, transition="auto"), PackModel(params, transition="expm")
    decoupled = law in ("none", "coulomb", "ff_t")
    assert auto.transition_method == ("closed form" if decoupled else "expm")
    assert ref.transition_method == "expm"
    rng = np.random.default_rng(11)
    dts = 1e-3 + np.abs(rng.normal(0.0, 3e-5, 3000))
    press = 20e5 + 15e5 * np.sin(np.cumsum(dts) * 2.0)
    rows = {}
    for model in (auto, ref):
        model.reset(press[0], 40.0, W10)
        rows[id(model)] = [model.step(float(dt), float(p), W10, 40.0)
                           for dt, p in zip(dts, press)]
    for name, tol in tolerance.items():
        got = np.array([getattr(s, name) for s in rows[id(auto)]])
        want = np.array([getattr(s, name) for s in rows[id(ref)]])
        if not decoupled:  # the same code path: the same bits
            np.testing.assert_array_equal(got, want, err_msg=name)
            continue
        scale = np.abs(want).max()
        assert_allclose(got, want, rtol=0, atol=tol * scale, err_msg=name)
    assert auto.misses == ref.misses > 10  # one per distinct 10 µs dt, either way
