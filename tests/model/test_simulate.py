"""simulate() equals looping step(); input validation of series."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import (
    DuplicateSample,
    InputError,
    NonFiniteSample,
    OutOfOrderSample,
    PackModel,
    simulate,
)
from clutch_ros.model.sequences import concatenate, pbd_sequence, ramp_sequence, table3

BOX_LAWS = ("coulomb", "ff_t", "ff_v")
FIELDS = ("torque", "reference_torque", "mu", "normal_force", "spline_force", "front_pressure",
          "rear_pressure", "pressure_difference", "compression")


def _inputs():
    # ramp + PBD slip reversal, jittery stamps (whole microseconds and not), rising temperature
    seq = concatenate([ramp_sequence(4.0, 30.0, 1e-3, lead_out=0.5),
                       pbd_sequence(10.0, 35.0, 1e-3, lead_in=0.2, lead_out=0.5)])
    rng = np.random.default_rng(5)
    t = seq.t + rng.uniform(-3e-4, 3e-4, seq.t.size)
    t[0] = 0.0
    temp = 35.0 + 20.0 * seq.t / seq.t[-1]
    return t, seq.actuating_pressure, seq.slip_speed, temp


def _assert_equals_step_loop(params, res, t, p, w, temp):
    """Compare ``res`` with reset() + output() + step() per sample; return the loop's model.

    numpy engine: same per-sample code; only mu is computed vectorised (may differ in the last
    bit), so each field agrees to 1e-9 of its largest magnitude. Compiled kernel: the same
    operations, the ZOH product summed in another order, so fields agree to the same 1e-9,
    except the pressure difference front − rear: it cancels two pressures of up to ~1e7 Pa, so
    it keeps their absolute rounding (observed ~2e-7 Pa where it is ~0.03 Pa); it is held to
    1e-9 of the front pressure's largest magnitude instead; and the spline forces of the box
    laws (coulomb, passive ff_t / ff_v): step() keeps the previous active set while its
    conditions hold to 1e-9 of F_act, the kernel re-solves to 1e-12, so the stuck forces differ
    by the stuck subsystem's amplification of that (observed ≤ 3e-8 of the largest force);
    held to 1e-6 of the largest force, the tolerance tests/model/test_kernel.py uses.
    """
    model = PackModel(params)
    model.reset(p[0], temp[0], w[0])
    samples = [model.output(p[0], w[0], temp[0])]
    samples += [model.step(t[k] - t[k - 1], p[k], w[k], temp[k]) for k in range(1, t.size)]
    for name in FIELDS:
        loop = np.array([getattr(s, name) for s in samples])
        scale = max(np.abs(loop).max(), 1e-300)
        if name == "pressure_difference" and res.engine == "kernel":
            scale = np.abs(res.front_pressure).max()
        if name == "spline_force" and res.engine == "kernel" and params.spline.law in BOX_LAWS:
            scale *= 1e3  # atol 1e-6 of the largest force (docstring)
        assert_allclose(getattr(res, name), loop, rtol=0, atol=1e-9 * scale, err_msg=name)
    return model


@pytest.mark.parametrize("engine", ["numpy", "kernel"])
@pytest.mark.parametrize("law", ["none", "ff_t", "ff_v", "coulomb"])
def test_simulate_equals_step_loop(flexiforce, law, engine):
    params = flexiforce.with_law(law)
    t, p, w, temp = _inputs()
    res = simulate(params, t, p, w, temp, engine=engine)
    assert res.engine == engine
    _assert_equals_step_loop(params, res, t, p, w, temp)
    assert res.law == law and len(res) == t.size
    assert res.normal_force.shape == (t.size, 8) and res.positions.shape == (t.size, 8)


def test_initial_pressure_and_scalars(flexiforce):
    t = np.arange(0.0, 0.2, 1e-3)
    res = simulate(flexiforce, t, 40e5, 1.0, 35.0, initial_pressure=0.0)
    assert res.compression[0] == 0.0 and res.compression[-1] > 0.0
    res = simulate(flexiforce, t, 40e5, 1.0, 35.0)  # default: start at equilibrium at p[0]
    assert_allclose(res.compression, res.compression[0], rtol=1e-12)
    single = simulate(flexiforce, [0.0], 20e5, 1.0, 35.0)
    assert len(single) == 1


@pytest.mark.parametrize("t, p, err", [
    ([0.0, 1e-3, math.nan], 1e5, NonFiniteSample),
    ([0.0, 1e-3, 2e-3], [1e5, math.inf, 1e5], NonFiniteSample),
    ([0.0, 2e-3, 1e-3], 1e5, OutOfOrderSample),
    ([0.0, 1e-3, 1e-3], 1e5, DuplicateSample),
    ([0.0, 1e-3, 2e-3], [1e5, 1e5], InputError),
    ([], 1e5, InputError),
    ([[0.0, 1e-3]], 1e5, InputError),
])
def test_bad_series_rejected(flexiforce, t, p, err):
    with pytest.raises(err):
        simulate(flexiforce, t, p, 1.0, 35.0)


def test_model_reuse_keeps_cache(flexiforce):
    model = PackModel(flexiforce)
    t = np.arange(0.0, 0.5, 1e-3)
    a = simulate(flexiforce, t, 30e5, 1.0, 35.0, model=model)
    assert len(model._cache) == 1
    b = simulate(flexiforce, t, 30e5, 1.0, 35.0, model=model)
    assert_allclose(a.torque, b.torque, rtol=0, atol=0)  # reset each time: same result


@pytest.mark.parametrize("law", ["ff_v", "coulomb"])
@pytest.mark.parametrize("slip", [10.0, -10.0])
@pytest.mark.parametrize("engine", ["numpy", "kernel"])
def test_batch_kernels_equal_step_loop_on_table3(flexiforce, truth, law, slip, engine):
    """Uniform 1 ms Table 3 (step, incremented step, 4 s ramp): the batch paths equal step().

    ff_v writes its rows in place; coulomb advances blocks of an unchanged sliding set and
    checks them per block. Both equal step() to 1e-9 and leave the model in the same state.
    """
    params = (truth if law == "coulomb" else flexiforce).with_law(law)
    seq = concatenate(table3(slip, 1e-3)[:3])
    t, p, w, temp = seq.t, seq.actuating_pressure, seq.slip_speed, seq.lamella_temperature
    batch = PackModel(params)
    res = simulate(params, t, p, w, temp, model=batch, engine=engine)
    model = _assert_equals_step_loop(params, res, t, p, w, temp)
    end, ref = batch.state, model.state
    assert_allclose(end.work, ref.work, rtol=1e-9, atol=1e-9 * np.abs(ref.work).max())
    if law == "coulomb":
        assert np.array_equal(end.warm[0], ref.warm[0])
        assert np.array_equal(end.warm[1], ref.warm[1])
