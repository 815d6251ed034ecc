"""Drivetrain compliance with a sticking clutch (model/compliance.py, issue 24).

Closed forms: while the clutch sticks the torque is ``k ω_m t + c ω_m`` (the Test A delay),
it breaks away at the static capacity and then carries the kinetic one; a reversal of the
measured slip sticks it again and unwinds the shafts linearly. Passivity: the clutch's
dissipation ``T ω_c`` is never negative and the work fed at the measuring point equals the
stored spring energy plus the clutch's and the damper's dissipation. Paths: the compiled
series equals the per-sample Python step bit for bit; the estimator's per-sample update, the
batch over the kernel and over numpy, and a batch fed in pieces agree; with the stiffness 0
every output is exactly the one without the compliance.
"""

import math

import numpy as np
import pytest

from clutch_ros.model import ClutchEstimator, kernel, make_sequence
from clutch_ros.model.batch import BatchEstimator, estimate_batch
from clutch_ros.model.compliance import (
    Drivetrain,
    capacities,
    capacity_scalar,
    drive_series,
    stored_energy,
)
from clutch_ros.model.errors import InputError, ParameterError

K, C = 2000.0, 40.0  # [N m/rad], [N m s/rad]


@pytest.fixture()
def elastic(flexiforce):
    return flexiforce.replace(**{"drivetrain.stiffness": K, "drivetrain.damping": C})


def _run(params, dt, omega, t_kin, t_static, state=(0.0, 0.0)):
    drive = Drivetrain(params)
    drive.state[:] = state
    torque, slip, twist = [], [], []
    for w, tk, ts in zip(omega, t_kin, t_static):
        torque.append(drive.step(dt, w, tk, ts))
        slip.append(drive.clutch_slip)
        twist.append(drive.twist)
    return np.array(torque), np.array(slip), np.array(twist)


def test_stick_ramp_break_away_and_slip_closed_form(elastic):
    dt, w, t_kin, t_static = 1e-3, 0.2, 1000.0, 1100.0
    n = 4000
    torque, slip, _ = _run(elastic, dt, np.full(n, w), np.full(n, t_kin), np.full(n, t_static))
    t = dt * np.arange(1, n + 1)
    t_break = (t_static - C * w) / (K * w)  # 2.73 s
    stuck = t < t_break - dt
    np.testing.assert_allclose(torque[stuck], K * w * t[stuck] + C * w, rtol=1e-9)
    assert np.all(slip[stuck] == 0.0)
    after = t > t_break + dt
    np.testing.assert_array_equal(torque[after], t_kin)  # massless hub: the kinetic torque
    assert np.all(slip[after] > 0.0)
    assert slip[-1] == pytest.approx(w, rel=1e-9)  # settled: the clutch slips at ω_m
    # the build-up time is inversely proportional to ω_m (the thesis's Test A delay)
    for speed in (w, 5 * w):
        ramp, _, _ = _run(elastic, dt, np.full(n, speed), np.full(n, t_kin),
                          np.full(n, t_static))
        build_up = (np.argmax(ramp >= 0.9 * t_kin) + 1) * dt
        assert build_up == pytest.approx((0.9 * t_kin - C * speed) / (K * speed), abs=dt)


def test_reversal_sticks_and_unwinds_linearly(elastic):
    dt, t_kin, t_static = 1e-3, 1000.0, 1100.0
    w = np.concatenate([np.full(2000, 1.0), np.full(3000, -0.5)])
    torque, slip, _ = _run(elastic, dt, w, np.full(w.size, t_kin), np.full(w.size, t_static))
    assert torque[1999] == t_kin and slip[1999] > 0.0
    # stuck from the first reversed step on: T = k θ + c ω_m, falling at k |ω_m|
    seg = slice(2001, 4000)  # (T_k + T_s) / (k |ω_m|) = 2.1 s to unwind
    assert np.all(slip[seg] == 0.0)
    np.testing.assert_allclose(np.diff(torque[seg]), -K * 0.5 * dt, rtol=1e-8)
    assert torque[-1] == -t_kin and slip[-1] < 0.0  # broke away backwards, slips at -T_k


def test_passive_and_energy_balance(elastic):
    dt = 1e-4
    t = dt * np.arange(60000)
    omega = 0.6 * np.sin(2 * np.pi * 0.5 * t) + 0.05 * np.sin(2 * np.pi * 7 * t)
    t_kin = 600.0 + 400.0 * np.sin(2 * np.pi * 0.3 * t) ** 2
    t_static = 1.2 * t_kin
    torque, slip, twist = _run(elastic, dt, omega, t_kin, t_static)
    assert np.all(torque * slip >= 0.0)  # the clutch never feeds energy
    rate = omega - slip  # twist rate
    work_in = float(np.sum(torque * omega) * dt)
    clutch = float(np.sum(torque * slip) * dt)
    damper = float(np.sum(C * rate * rate) * dt)
    stored = stored_energy(elastic, twist[-1]) - stored_energy(elastic, 0.0)
    assert clutch > 0.0 and damper > 0.0
    assert work_in == pytest.approx(stored + clutch + damper, rel=2e-3)


def test_compiled_series_equals_the_python_step_bit_for_bit(elastic):
    if not kernel.available():
        pytest.skip(kernel.unavailable_reason() or "no kernel")
    rng = np.random.default_rng(3)
    n = 5000
    omega = np.cumsum(rng.normal(0.0, 0.02, n))
    t_kin = np.abs(800.0 + np.cumsum(rng.normal(0.0, 5.0, n)))
    t_static = 1.15 * t_kin
    dts = np.full(n - 1, 1e-3) + rng.uniform(-5e-5, 5e-5, n - 1)
    out = {}
    for engine in ("kernel", "numpy"):
        state = np.array([0.1, 0.0])
        out[engine] = (*drive_series(elastic, dts, omega, t_kin, t_static, state, engine),
                       state.copy())
    for a, b in zip(out["kernel"], out["numpy"]):
        np.testing.assert_array_equal(a, b)


def test_capacities_scalar_and_array_agree(elastic):
    mu = np.array([0.1, 0.12, 0.13])
    z = np.array([-1e-5, 2e-4, 4e-4])
    temp = np.array([35.0, 60.0, 80.0])
    tk, ts = capacities(elastic, mu, z, temp)
    for i in range(3):
        assert (tk[i], ts[i]) == capacity_scalar(elastic, mu[i], z[i], temp[i])
    assert tk[0] == 0.0 and np.all(ts >= tk)


def _series():
    seq = make_sequence("pbd", 10.0)
    rng = np.random.default_rng(7)
    omega = seq.slip_speed + rng.normal(0.0, 0.005, seq.t.size)
    return seq.t, seq.actuating_pressure, omega


def test_estimator_batch_kernel_numpy_and_pieces_agree(elastic):
    t, p, omega = _series()
    est = ClutchEstimator(elastic)
    loop = [est.update(a, b, 35.0, c) for a, b, c in zip(t, p, omega)]
    torque = np.array([e.modelled_torque for e in loop])
    slip = np.array([e.clutch_slip_speed for e in loop])
    fast = estimate_batch(elastic, t, p, 35.0, omega, engine="kernel"
                          if kernel.available() else "auto")
    ref = estimate_batch(elastic, t, p, 35.0, omega, engine="numpy")
    for batch in (fast, ref):
        np.testing.assert_allclose(batch.modelled_torque, torque, rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(batch.clutch_slip_speed, slip, rtol=1e-9, atol=1e-9)
    stream = BatchEstimator(elastic, t.size)
    for a, b in ((0, 700), (700, 701), (701, t.size)):
        stream.feed(t[a:b], p[a:b], 35.0, omega[a:b])
    pieces = stream.result()
    np.testing.assert_array_equal(pieces.modelled_torque, fast.modelled_torque)
    np.testing.assert_array_equal(pieces.clutch_slip_speed, fast.clutch_slip_speed)
    # standstill under pressure: the stuck clutch carries what the shafts impose, not the
    # slip sensor's noise times the capacity
    still = (t > 1.2) & (t < 2.0)
    assert np.all(slip[still] == 0.0)
    assert np.std(torque[still]) < 0.05 * np.std(
        estimate_batch(elastic.replace(**{"drivetrain.stiffness": 0.0}), t, p, 35.0,
                       omega).modelled_torque[still])


def test_stiffness_zero_is_exactly_the_rigid_model(flexiforce):
    t, p, omega = _series()
    off = flexiforce.replace(**{"drivetrain.stiffness": 0.0, "drivetrain.damping": 55.0})
    a = estimate_batch(flexiforce, t, p, 35.0, omega)
    b = estimate_batch(off, t, p, 35.0, omega)
    np.testing.assert_array_equal(a.modelled_torque, b.modelled_torque)
    assert np.isnan(b.clutch_slip_speed).all()
    est = ClutchEstimator(off)
    ref = ClutchEstimator(flexiforce)
    for k in range(0, t.size, 97):
        x, y = est.update(t[k], p[k], 35.0, omega[k]), ref.update(t[k], p[k], 35.0, omega[k])
        assert x.modelled_torque == y.modelled_torque and math.isnan(x.clutch_slip_speed)


def test_parameters_have_units_and_ranges(flexiforce):
    from clutch_ros.model.params import PARAMETER_SPECS

    assert PARAMETER_SPECS["drivetrain.stiffness"].unit == "N m/rad"
    assert PARAMETER_SPECS["drivetrain.damping"].unit == "N m s/rad"
    assert flexiforce.drivetrain.stiffness == 0.0  # off by default
    with pytest.raises(ParameterError, match="drivetrain.stiffness"):
        flexiforce.replace(**{"drivetrain.stiffness": -1.0})
    with pytest.raises(InputError, match="stiffness"):
        Drivetrain(flexiforce)
