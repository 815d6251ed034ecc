"""Oil-film friction (Hypothesis 2), the estimator's thermal state and forward/inverse agreement."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import PackModel, simulate, solve_pressure
from clutch_ros.model.film import film_step, thermal_step
from clutch_ros.model.sequences import pbd_release_sequence, pbd_sequence, step_sequence


def test_film_step_closed_form(truth):
    fr = truth.friction
    # pressed at standstill: pure thinning, φ = e^{-t (p/p_ref) / τ_thin}
    phi = 1.0
    for _ in range(500):
        phi = film_step(fr, phi, 1e-3, 40e5, 0.0)
    assert_allclose(phi, math.exp(-0.5 * (40e5 / fr.pressure_ref) / fr.film_thinning_time),
                    rtol=1e-12)
    # open at standstill: nothing changes; sliding fast: recovery with τ_rec
    assert film_step(fr, 0.3, 0.1, 0.0, 0.0) == 0.3
    rec = film_step(fr, 0.3, 0.1, 0.0, 100.0)
    assert_allclose(1.0 - rec, 0.7 * math.exp(-0.1 / fr.film_recovery_time), rtol=1e-12)


def test_pbd_spike_with_film_and_not_without(truth):
    """Fig. 46: PBD torque spikes at slip onset (film thinned at standstill), DBP does not."""
    seq = pbd_sequence(10.0, 35.0)
    res = simulate(truth, seq.t, seq.actuating_pressure, seq.slip_speed, 35.0)
    onset = seq.active[0] + 1.0
    window = (seq.t > onset) & (seq.t < onset + 0.5)
    settled = (seq.t > onset + 2.5) & (seq.t < onset + 3.4)
    spike = res.torque[window].max() / res.torque[settled].mean()
    # bounded by the static ratio, and a clear spike (thinned film: 0.8 × (1.25 − 1))
    assert 1.08 < spike <= truth.friction.static_ratio
    assert res.film[window].min() < 0.6
    off = simulate(truth.replace(**{"friction.film_depth": 0.0}), seq.t,
                   seq.actuating_pressure, seq.slip_speed, 35.0)
    assert off.torque[window].max() / off.torque[settled].mean() < 1.01
    dbp = step_sequence(10.0)
    res = simulate(truth, dbp.t, dbp.actuating_pressure, dbp.slip_speed, 35.0)
    assert res.film.min() > 0.99  # slipping while pressed: the film never thins


@pytest.mark.parametrize("law", ["none", "ff_t", "coulomb"])
def test_simulate_equals_step_loop_with_film_and_thermal_state(truth, law):
    params = truth.with_law(law).replace(**{"friction.film_depth": 0.8})
    seq = pbd_release_sequence(10.0, dt=2e-3)
    temp = np.where(seq.t < 4.0, 35.0, np.nan)  # sensor lost at 4 s: thermal state takes over
    res = simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed, temp)
    model = PackModel(params)
    model.reset(seq.actuating_pressure[0], temp[0], seq.slip_speed[0])
    torques = [model.output(seq.actuating_pressure[0], seq.slip_speed[0], temp[0]).torque]
    for k in range(1, len(seq.t)):
        s = model.step(seq.t[k] - seq.t[k - 1], seq.actuating_pressure[k], seq.slip_speed[k],
                       temp[k])
        torques.append(s.torque)
    assert_allclose(res.torque, torques, rtol=1e-12, atol=1e-9)  # same code, rounding only


def test_thermal_state_follows_heating_and_measurement_wins(flexiforce):
    seq = step_sequence(30.0)
    measured = simulate(flexiforce, seq.t, seq.actuating_pressure, seq.slip_speed, 35.0)
    free = simulate(flexiforce, seq.t, seq.actuating_pressure, seq.slip_speed, np.nan)
    assert np.all(measured.lamella_temperature == 35.0)
    # heating by the modelled slip power: energy / heat capacity bounds the rise
    th = flexiforce.thermal
    energy = np.sum(np.abs(free.torque[1:] * free.slip_speed[1:]) * np.diff(seq.t))
    rise = free.lamella_temperature[-1] - th.oil_temperature
    assert 0.3 * energy / th.heat_capacity < rise < energy / th.heat_capacity
    assert free.torque[-4000] < measured.torque[-4000]  # hotter: lower μ (negative slope)
    # one exact step against the closed form
    t1 = thermal_step(th, 35.0, 10.0, 1200.0)
    target = th.oil_temperature + 1200.0 / th.conductance
    assert_allclose(t1, target + (35.0 - target) * math.exp(-10.0 * th.conductance
                                                             / th.heat_capacity), rtol=1e-14)


@pytest.mark.parametrize("slip", [0.01, 0.02, 0.05, 0.1, 0.5, 1.047, 3.14, -0.01, -0.3])
def test_forward_and_inverse_agree_down_to_001_rad_s(flexiforce, slip):
    params = flexiforce.with_law("none")
    for torque in (200.0, 800.0):
        sol = solve_pressure(params, torque, 50.0, slip)
        model = PackModel(params)
        model.reset(sol.pressure, 50.0, slip)
        out = model.step(1e-3, sol.pressure, slip, 50.0)
        # equilibrium of the forward model: μ at the pack's normal force = μ at p; sign ±1
        assert_allclose(abs(out.torque), torque, rtol=1e-9)
        assert math.copysign(1.0, out.torque) == math.copysign(1.0, slip)
