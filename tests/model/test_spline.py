"""Spline-friction laws: ff_t (Eq. 29) and ff_v (Eq. 30) closed forms, coulomb stiction."""

import math
import types

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    PackModel,
    make_spline_law,
    ramp_sequence,
    reference_torque,
    simulate,
    slip_sign,
)
from clutch_ros.model.metrics import hysteresis_width
from clutch_ros.model.spline import TorqueFilterLaw
from clutch_ros.model.spline_passive import _violations, box_forces, solve_box

W10 = 10 * 2 * math.pi / 60  # [rad/s]


def test_make_spline_law_names(flexiforce):
    kinds = {law: type(make_spline_law(flexiforce.with_law(law))).__name__
             for law in ("none", "ff_t", "ff_v", "coulomb", "ff_t_printed", "ff_v_printed")}
    assert kinds == {"none": "SplineLaw", "ff_t": "PassiveTorqueFilterLaw",
                     "ff_v": "PassiveViscousLaw", "coulomb": "CoulombLaw",
                     "ff_t_printed": "TorqueFilterLaw", "ff_v_printed": "ViscousLaw"}
    assert make_spline_law(flexiforce) is not make_spline_law(flexiforce)  # one per model


@pytest.mark.parametrize("tau", [1.0, 3.0])
def test_ff_t_torque_step_response_is_kappa_t_exp(flexiforce, tau):
    """Thesis Fig. 52: F_f after a torque step T at t = 0 is κ T e^{-t/τ}, at any dt."""
    params = flexiforce.replace(**{"spline.time_constant": tau})
    model = PackModel(params)
    lay = model.layout
    kappa, torque = params.spline.gain, 1000.0
    rng = np.random.default_rng(3)
    dts_us = rng.integers(10, 5_000, 300) * 10  # whole 10 us: exact cache quantisation
    t = np.cumsum(dts_us) * 1e-6
    work = np.zeros(lay.size)
    work[lay.i_torque] = torque  # T steps from 0 (y = 0) to 1000 N m at t = 0
    forces = []
    for dt in dts_us * 1e-6:
        m = model.discretisation(dt).M
        work[lay.n_pack] = m[lay.n_pack] @ work  # the filter row of the pack's own ZOH
        forces.append(kappa * torque - work[lay.n_pack])
    # e^{-dt/tau} from expm of the (block-triangular) step matrix: rounding-level agreement
    assert_allclose(forces, TorqueFilterLaw.step_response(kappa, tau, torque, t),
                    rtol=1e-12, atol=1e-12 * kappa * torque)


def test_ff_t_printed_first_step_inside_the_pack(flexiforce):
    # pack compressed at zero slip (no torque, y = 0); then the slip starts: the law sees a
    # torque step and reports κ T e^{-dt/τ} at the end of the first step, whatever the pack does
    params = flexiforce.with_law("ff_t_printed")
    model = PackModel(params)
    model.reset(40e5, 35.0, 0.0)
    torque = model.output(40e5, W10, 35.0).torque  # T seen by the law (state at the start)
    sample = model.step(0.02, 40e5, W10, 35.0)
    expected = params.spline.gain * torque * math.exp(-0.02 / params.spline.time_constant)
    assert_allclose(sample.spline_force, expected, rtol=1e-12)
    assert sample.torque < torque  # the loss acts inside the step already


def test_ff_v_filter_follows_closed_form(flexiforce):
    """Eq. 30's filter state w_n = 1/(τs+1) ż_n for a pressure step, with feedback negligible.

    With κ tiny the pack moves as z_n(t) = z_n,ss (1 - e^{-t/τp}), τp = c/k, so
    w_n(t) = z_n,ss (e^{-t/τ} - e^{-t/τp}) / (τ - τp).
    """
    params = flexiforce.with_law("ff_v").replace(**{"spline.gain": 1e-9})
    pk = params.pack
    tau, tau_p = params.spline.time_constant, pk.lamella_damping / pk.lamella_stiffness
    model = PackModel(params)
    model.reset(0.0, 35.0, W10)
    lay = model.layout
    z_ss = np.arange(1, 9) * 40e5 * pk.piston_area / pk.lamella_stiffness
    for k in range(1, 3001):
        model.step(1e-3, 40e5, W10, 35.0)
        if k % 500 == 0:
            t = k * 1e-3
            w = model.state.work[lay.law_states]
            expected = z_ss * (math.exp(-t / tau) - math.exp(-t / tau_p)) / (tau - tau_p)
            # single slow root -k/c is exact to ~3e-6; the filter itself is exact
            assert_allclose(w, expected, rtol=1e-5)


@pytest.mark.parametrize("law", ["ff_t", "ff_v"])
def test_thesis_laws_vanish_at_steady_state(flexiforce, law):
    params = flexiforce.with_law(law)
    t = np.arange(0.0, 40.0, 5e-3)
    res = simulate(params, t, np.where(t > 1.0, 40e5, 0.0), W10, 35.0)
    peak = np.abs(res.spline_force).max()
    assert peak > 50.0  # a real transient loss (N per lamella) ...
    assert np.abs(res.spline_force[-1]).max() < 1e-6 * peak  # ... gone after 19+ tau
    # what is left: ff_v e^{-39/2} ~ 3e-9 of a ~10 % loss (ff_t: rounding only)
    assert_allclose(res.torque[-1], reference_torque(params, 40e5, 35.0, W10), rtol=1e-8)


def _coulomb_a(params, mu, slip):
    sp, pk = params.spline, params.pack
    return (mu * sp.friction_coefficient * pk.effective_radius / sp.radius
            * abs(slip_sign(params, slip)))


def test_coulomb_quasi_static_force_ratio(truth):
    dt = 0.5  # exact ZOH at any dt: a very slow ramp (4 bar per 1000 s) at few samples
    t = np.arange(0.0, 22000.0, dt)
    p = np.interp(t, [0.0, 10000.0, 11000.0, 21000.0, 22000.0], [0.0, 40e5, 40e5, 0.0, 0.0])
    res = simulate(truth, t, p, W10, 35.0)
    area = truth.pack.piston_area
    for time, loading in ((5000.0, True), (16000.0, False)):
        k = int(time / dt)
        a = _coulomb_a(truth, res.mu[k], W10)
        s = res.normal_force[k]
        ratios = np.append(s[:-1] / s[1:], s[-1] / (p[k] * area))  # below/above each plate
        expected = (1 - a) / (1 + a) if loading else (1 + a) / (1 - a)
        # sliding plates: quasi-static ratio; the damping lag (c/k * dF/dt ~ 0.15 N of 7.5 kN)
        # and the bound taken at the step start (~1e-6) leave < 1e-4
        assert_allclose(ratios, expected, rtol=1e-4)
        assert abs(ratios[0] - 1.0) > 0.01  # and the effect is not negligible


def test_coulomb_sticks_inside_the_friction_cone(truth):
    t = np.arange(0.0, 7.0, 1e-3)
    # ramp to 40 bar, hold 2 s: the pack creeps towards the sliding equilibrium, where the
    # holding force equals the bound (so it approaches the stick limit exponentially)
    p = np.interp(t, [0.0, 0.5, 3.0, 5.0, 5.001, 7.0], [0.0, 0.0, 40e5, 40e5, 39.8e5, 39.8e5])
    res = simulate(truth, t, p, W10, 35.0)
    creep = np.abs(np.diff(res.positions[3000:5000], axis=0)).max(axis=1)
    assert creep[-1] < 1e-6 * creep[0]  # converging, not drifting
    # a 0.2 bar release stays inside the friction cone: every lamella sticks, nothing moves
    # (moves of 1e-16 m on 3e-4 m, 3e-13 relative, are the active-set tolerance of 1e-12)
    held = res.positions[5002:]
    assert_allclose(held, np.broadcast_to(held[0], held.shape), rtol=0, atol=1e-15)  # m
    assert res.pressure_difference[-1] > 0.05 * 40e5  # persistent P_diff (never decays)
    assert res.torque[-1] < reference_torque(truth, 39.8e5, 35.0, W10) * 0.97


def test_coulomb_never_injects_energy(truth):
    seq = ramp_sequence(4.0, 10.0, 1e-3)
    res = simulate(truth, seq.t, seq.actuating_pressure, seq.slip_speed, 35.0)
    moved = np.diff(res.positions, axis=0)
    work = res.spline_force[1:] * moved  # F_fn opposes compression: F_fn dz_n >= 0
    scale = np.abs(res.spline_force).max() * np.abs(moved).max()
    assert work.min() >= -1e-9 * scale  # rounding only
    assert work.sum() > 0.0


def test_coulomb_is_frictionless_without_torque(truth):
    t = np.arange(0.0, 2.0, 1e-3)
    p = np.where(t > 0.5, 40e5, 0.0)
    res = simulate(truth, t, p, 0.0, 35.0)  # zero slip: no torque, no spline load
    free = simulate(truth.replace(**{"spline.law": "none"}), t, p, 0.0, 35.0)
    assert np.all(res.spline_force == 0.0)
    assert_allclose(res.normal_force, free.normal_force, rtol=1e-14, atol=0)


def test_coulomb_dt_independent(truth):
    def run(dt):
        t = np.arange(0.0, 12.0 + dt / 2, dt)
        p = np.interp(t, [0.0, 1.0, 7.0, 12.0], [0.0, 0.0, 40e5, 40e5])
        return simulate(truth, t, p, W10, 35.0).rear_pressure[-1]
    fine, coarse = run(1e-3), run(2e-2)
    # time stepping does not depend on dt beyond the bound lag of one step
    assert_allclose(coarse, fine, rtol=2e-3)


def test_coulomb_active_set_equals_projected_gauss_seidel(truth):
    # the fast active-set iteration and the guaranteed PGS fallback solve the same
    # box-constrained problem: random right-hand sides, same unique solution
    model = PackModel(truth)
    entry = model.discretisation(1e-3)
    law = model.law
    rng = np.random.default_rng(11)
    for _ in range(40):
        f_stick = rng.normal(0.0, 300.0, 8)
        bound = rng.uniform(0.0, 300.0, 8)
        law.set_warm_state(None)
        f_as = law._solve(entry, f_stick, bound)
        f_gs = law._gauss_seidel(entry, f_stick, bound)
        assert_allclose(f_as, f_gs, rtol=0, atol=1e-9)  # N: both end in the same exact solve
        dz = entry.coulomb_g @ (f_as - f_stick)
        stuck = np.abs(f_as) < bound * (1 - 1e-9)
        assert_allclose(dz[stuck], 0.0, atol=1e-18)  # m: stuck plates do not move
        assert np.all(f_as[~stuck] * dz[~stuck] >= -1e-18)  # sliding: force opposes motion


def test_hysteresis_24s_triangle_zero_for_thesis_laws_clear_for_coulomb(flexiforce, truth):
    """Pressure triangle 0-40-0 bar in 24 s with holds at 20 bar on both legs.

    After settling (15 s holds, > 7 τ of ff_t/ff_v at 10 rpm), the thesis laws' spline force
    has decayed, so the torque at 20 bar is the same on both legs (width ≈ 0); the coulomb
    law keeps the pack stuck: less torque after compression, more after rebound (Tables 5-6).
    """
    seq = ramp_sequence(24.0, 10.0, 2e-3, hold_at=(20e5,), hold_time=15.0)
    widths = {}
    for name, params in (("ff_t", flexiforce), ("ff_v", flexiforce.with_law("ff_v")),
                         ("coulomb", truth)):
        res = simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed,
                       seq.lamella_temperature)
        torque_20 = reference_torque(params, 20e5, 35.0, W10)
        widths[name] = hysteresis_width(seq.actuating_pressure, res.torque, 20e5) / torque_20
    # residual after 15 s: ff_t e^{-15/0.94} ~ 1e-7, ff_v e^{-15/2} ~ 6e-4 of a ~1 % loss
    assert abs(widths["ff_t"]) < 1e-5
    assert abs(widths["ff_v"]) < 1e-4
    assert widths["coulomb"] > 0.05  # ~ +/-5 % per leg: clearly a loop
    # without holds the loop exists for every law while moving, but is widest for coulomb
    seq = ramp_sequence(24.0, 10.0, 2e-3)
    res = simulate(truth, seq.t, seq.actuating_pressure, seq.slip_speed, 35.0)
    assert hysteresis_width(seq.actuating_pressure, res.torque, 20e5) > widths["ff_t"]


def _array_apply(law, entry, torque, mu_load):
    """PassiveLaw.apply written on numpy arrays (its form before the float-by-float path)."""
    scale = law.coef * mu_load
    des = law.desired(torque)
    if scale <= 0.0 or not des.any():
        law._f.fill(0.0)
        return
    normal = np.maximum(entry.passive_normal.dot(law._head), 0.0)
    bound = (normal[:-1] + normal[1:]) * scale
    clipped = np.clip(des, -bound, bound)
    hi, lo = np.maximum(clipped, 0.0), np.minimum(clipped, 0.0)
    f_stick = entry.passive_stick.dot(law._head)
    g, stuck, sigma = entry.passive_g, law._stuck, law._sigma
    if not stuck.any():
        f = np.where(sigma > 0.0, hi, lo)
        dz = g.dot(f - f_stick)
        if ((sigma * dz >= -1e-12 * (np.abs(dz).max() + 1e-15)) | (hi <= lo)).all():
            law._f[:] = f
            return
    else:
        f = box_forces(g, f_stick, lo, hi, stuck, sigma, entry.passive_solves)
        if not any(v.any() for v in _violations(g, f_stick, f, lo, hi, stuck, sigma)):
            law._f[:] = f
            return
    f, law._stuck, law._sigma, _ = solve_box(g, entry.passive_h, f_stick, lo, hi, stuck,
                                             sigma, entry.passive_solves)
    law._f[:] = f


@pytest.mark.parametrize("law", ["ff_t", "ff_v"])
@pytest.mark.parametrize("friction", [0.05, 0.5])
def test_passive_apply_equals_its_array_form_bit_for_bit(flexiforce, law, friction):
    # the per-step path works on Python floats with the same operations: the same bits, on
    # a jittery 1 kHz stream that slides and (with 10x the spline friction) sticks
    params = flexiforce.with_law(law).updated({"spline.friction_coefficient": friction})
    fast, ref = PackModel(params), PackModel(params)
    ref.law.apply = types.MethodType(_array_apply, ref.law)
    rng = np.random.default_rng(3)
    dts = 1e-3 + np.abs(rng.normal(0.0, 2e-5, 4000))
    t = np.cumsum(dts)
    press = np.clip(30e5 * np.sin(t * 1.3) + 5e5 * np.sin(t * 9.0), 0.0, None)
    slip = W10 * np.sign(np.sin(t * 0.7) + 0.2)
    out = {}
    for model in (fast, ref):
        model.reset(0.0, 40.0, slip[0])
        rows = [model.step(float(d), float(p), float(w), 40.0) for d, p, w in zip(dts, press,
                                                                                   slip)]
        out[id(model)] = (np.array([r.torque for r in rows]),
                          np.array([r.spline_force for r in rows]))
    for got, want in zip(out[id(fast)], out[id(ref)]):
        np.testing.assert_array_equal(got, want)
    assert np.abs(out[id(ref)][1]).max() > 0.0  # the law acted
