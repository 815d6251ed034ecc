"""ClutchEstimator: rejection without side effects, gaps, accuracy, batch == loop."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    ClutchEstimator,
    DuplicateSample,
    NonFiniteSample,
    OutOfOrderSample,
    SampleRejected,
    estimate_batch,
    reference_torque,
)
from clutch_ros.model.sequences import concatenate, incremented_step_sequence, pbd_sequence

FIELDS = ("modelled_torque", "reference_torque", "measured_torque", "torque_accuracy",
          "friction_coefficient", "lamella_normal_force", "spline_friction_force",
          "front_pressure", "rear_pressure", "pressure_difference", "slip_speed_filtered",
          "overshoot", "undershoot", "compression", "spline_correction")


def _snapshot(est):
    return (est.last_stamp, est.slip_filter.value, est.pack.state.work.copy())


def _feed(est, n=50, t0=0.0):
    for k in range(n):
        est.update(t0 + k * 1e-3, 30e5, 40.0, 1.0, 900.0)


@pytest.mark.parametrize("bad", [
    (math.nan, 30e5, 40.0, 1.0, 900.0),
    (math.inf, 30e5, 40.0, 1.0, 900.0),
    (1.0, math.nan, 40.0, 1.0, 900.0),
    (1.0, 30e5, -math.inf, 1.0, 900.0),
    (1.0, 30e5, 40.0, math.nan, 900.0),
    (1.0, 30e5, 40.0, 1.0, math.inf),
    (1.0, 30e5, 40.0, 1.0, "x"),
])
def test_non_finite_rejected_state_untouched(flexiforce, bad):
    est = ClutchEstimator(flexiforce)
    _feed(est)
    before = _snapshot(est)
    with pytest.raises(NonFiniteSample):
        est.update(*bad)
    after = _snapshot(est)
    assert before[:2] == after[:2] and np.array_equal(before[2], after[2])


def test_out_of_order_and_duplicate_rejected_and_state_kept(flexiforce):
    est, ref = ClutchEstimator(flexiforce), ClutchEstimator(flexiforce)
    _feed(est)
    _feed(ref)
    before = _snapshot(est)
    with pytest.raises(DuplicateSample):
        est.update(0.049, 10e5, 40.0, 1.0)
    with pytest.raises(OutOfOrderSample):
        est.update(0.010, 10e5, 40.0, 1.0)
    assert np.array_equal(_snapshot(est)[2], before[2]) and est.last_stamp == before[0]
    # the estimator continues exactly like one that never saw the bad samples
    a = est.update(0.050, 35e5, 40.0, 1.0, 950.0)
    b = ref.update(0.050, 35e5, 40.0, 1.0, 950.0)
    for name in FIELDS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert issubclass(DuplicateSample, SampleRejected)


def test_first_sample_is_equilibrium_and_accuracy(flexiforce):
    est = ClutchEstimator(flexiforce)
    ref = reference_torque(flexiforce, 40e5, 35.0, 1.0)
    e = est.update(10.0, 40e5, 35.0, 1.0, 1.2 * ref)
    assert e.reinitialised and e.spline_law == "ff_t"
    assert_allclose(e.modelled_torque, ref, rtol=1e-12)  # equilibrium: Eq. 27 = Eq. 1
    assert_allclose(e.torque_accuracy, 1.2, rtol=1e-12)
    assert e.overshoot and not e.undershoot
    e = est.update(10.001, 40e5, 35.0, 1.0, 0.85 * ref)
    assert e.undershoot and not e.overshoot and not e.reinitialised
    e = est.update(10.002, 40e5, 35.0, 1.0)  # no measurement
    assert math.isnan(e.torque_accuracy) and not (e.overshoot or e.undershoot)
    e = ClutchEstimator(flexiforce).update(0.0, 40e5, 35.0, 0.0, 5.0)  # zero slip: T = 0
    assert e.modelled_torque == 0.0 and math.isnan(e.torque_accuracy)


def test_gap_reinitialises(flexiforce):
    est = ClutchEstimator(flexiforce, max_gap_s=0.5)
    est.update(0.0, 0.0, 35.0, 1.0)
    est.update(0.001, 40e5, 35.0, 1.0)  # step: far from equilibrium
    e = est.update(0.4, 40e5, 35.0, 1.0)
    assert not e.reinitialised
    e = est.update(1.0, 10e5, 35.0, 1.0)  # 0.6 s gap
    assert e.reinitialised
    assert_allclose(e.modelled_torque, reference_torque(flexiforce, 10e5, 35.0, 1.0),
                    rtol=1e-12)
    assert np.all(e.spline_friction_force == 0.0)


def test_slip_is_filtered(flexiforce):
    est = ClutchEstimator(flexiforce)  # slip.filter_time_constant = 0.02 s
    est.update(0.0, 30e5, 35.0, 0.0)
    e = est.update(0.02, 30e5, 35.0, 1.0)
    assert_allclose(e.slip_speed_filtered, 1.0 - math.exp(-1.0), rtol=1e-12)
    assert e.slip_speed == 1.0


def test_set_params_keeps_state(flexiforce):
    est = ClutchEstimator(flexiforce)
    _feed(est, 200)
    z = est.pack.positions
    est.set_params(flexiforce.replace(**{"friction.mu_ref": 0.13,
                                         "slip.filter_time_constant": 0.1}))
    assert np.array_equal(est.pack.positions, z) and est.last_stamp == 0.199
    e = est.update(0.2, 30e5, 40.0, 1.0)
    assert not e.reinitialised and est.slip_filter.time_constant == 0.1
    est.set_params(flexiforce.with_law("coulomb"))
    e = est.update(0.201, 30e5, 40.0, 1.0)
    assert e.spline_law == "coulomb" and not e.reinitialised


def _series():
    seq = concatenate([incremented_step_sequence(30.0, 2e-3, lead_out=0.5),
                       pbd_sequence(10.0, 60.0, 2e-3, lead_in=0.2, lead_out=0.5)])
    t = seq.t.copy()
    rng = np.random.default_rng(9)
    t += rng.uniform(0.0, 4e-4, t.size)
    t[8000:] += 2.0  # a gap: re-initialisation
    measured = 1.05 * seq.actuating_pressure * 3e-4 * np.sign(seq.slip_speed)  # ~1.2 kN m
    measured[::7] = np.nan
    return t, seq.actuating_pressure, np.full(t.size, 40.0), seq.slip_speed, measured


@pytest.mark.parametrize("engine", ["numpy", "kernel"])
@pytest.mark.parametrize("law", ["ff_t", "coulomb"])
def test_batch_equals_update_loop(flexiforce, law, engine):
    params = flexiforce.with_law(law)
    t, p, temp, w, meas = _series()
    # bad samples: a duplicate, an out-of-order stamp, a NaN pressure, an inf measurement
    t[100], t[200] = t[99], t[150]
    p[300] = math.nan
    meas[400] = math.inf
    batch = estimate_batch(params, t, p, temp, w, meas, on_reject="skip", engine=engine)
    est = ClutchEstimator(params)
    rows = []
    for k in range(t.size):
        try:
            rows.append(est.update(t[k], p[k], temp[k], w[k], meas[k]))
        except SampleRejected:
            rows.append(None)
    accepted = np.array([r is not None for r in rows])
    assert np.array_equal(batch.accepted, accepted)
    assert not accepted[[100, 200, 300, 400]].any() and accepted.sum() == t.size - 4
    assert np.array_equal(batch.reinitialised[accepted], [r.reinitialised for r in rows if r])
    for name in FIELDS:
        loop = np.array([getattr(r, name) for r in rows if r is not None])
        got = getattr(batch, name)[accepted]
        if loop.dtype == bool:
            assert np.array_equal(got, loop), name
            continue
        scale = max(np.nanmax(np.abs(loop)), 1e-300)
        # same kernels; mu vectorised vs scalar may differ in the last bit
        if engine == "kernel" and law == "coulomb" and name in ("spline_friction_force",
                                                                 "spline_correction"):
            # the compiled loop re-solves the box to 1e-12 where step() keeps a set that
            # holds to 1e-9 of F_act: the spline forces (and their pressure equivalent) to
            # 1e-6 of the largest, as in test_kernel.py and test_simulate.py (observed 2e-9
            # to 7e-8)
            scale *= 1e3
        if engine == "kernel" and name == "pressure_difference":
            # front − rear cancels two pressures; it keeps their absolute rounding (and the
            # coulomb force difference above): 1e-9 of the front pressure, as in test_simulate
            scale = np.nanmax(np.abs(batch.front_pressure))
        assert_allclose(got, loop, rtol=0, atol=1e-9 * scale, equal_nan=True, err_msg=name)
    assert np.isnan(batch.modelled_torque[~accepted]).all()
    with pytest.raises(DuplicateSample):
        estimate_batch(params, t, p, temp, w, meas)  # on_reject="raise": first bad sample
