"""BatchEstimator: a series fed in pieces gives estimate_batch's result (clutch_ros/model/batch.py).

With the compiled kernel's output loop (every law but the printed ones) the pieces must give the
very same bits (every sample's arithmetic is scalar and runs in the same order whatever the
piece boundaries); with the numpy engine, and for ``ff_t_printed`` / ``ff_v_printed`` (their
outputs are computed vectorised after the loop), the last bit may round differently at a
piece's edge, so rtol 1e-12 there. The series has
every case the carried state must get right: rejected samples (non-finite, repeated, older
stamps) inside a piece and at its edges, a gap longer than max_gap_s inside a piece and exactly
at a piece boundary, no lamella temperature (thermal state carried), a film-on preset.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import BatchEstimator, OutOfOrderSample, estimate_batch, kernel
from clutch_ros.model.sequences import make_sequence

FIELDS = ("stamp", "accepted", "reinitialised", "modelled_torque", "reference_torque",
          "measured_torque", "torque_accuracy", "friction_coefficient", "lamella_normal_force",
          "spline_friction_force", "front_pressure", "rear_pressure", "pressure_difference",
          "slip_speed_filtered", "overshoot", "undershoot", "actuating_pressure",
          "lamella_temperature", "slip_speed", "compression", "spline_correction")


def _series(measured_temperature: bool):
    seq = make_sequence("pbd_release", 10.0)
    t = seq.t.copy()
    n = t.size
    gap_at = n // 2
    t[gap_at:] += 2.0  # longer than max_gap_s (1 s): a new segment
    p = seq.actuating_pressure.copy()
    p[7] = math.nan  # non-finite
    t[11] = t[10]  # repeated stamp
    t[gap_at + 3] = t[gap_at + 1]  # older than the last accepted
    temp = np.linspace(35.0, 90.0, n) if measured_temperature else np.full(n, math.nan)
    measured = np.where(np.arange(n) % 7 == 0, math.nan, 80.0)
    return t, p, temp, seq.slip_speed.copy(), measured, gap_at


def _stream(params, args, cuts, engine, capacity):
    stream = BatchEstimator(params, capacity, on_reject="skip", engine=engine)
    bounds = [0, *sorted(cuts), args[0].size]
    for a, b in zip(bounds[:-1], bounds[1:]):
        stream.feed(*(x[a:b] for x in args))
    return stream.result()


def _compare(whole, pieces, exact: bool, where: str):
    for name in FIELDS:
        a, b = getattr(pieces, name), getattr(whole, name)
        if exact or a.dtype == bool:
            np.testing.assert_array_equal(a, b, err_msg=f"{where}: {name}")
        else:
            # numpy engine: vectorised outputs, the last bit may differ at a piece's edge
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(b)),
                                       err_msg=f"{where}: {name}")


@pytest.mark.parametrize("law", sorted(kernel.LAW_CODES))
@pytest.mark.parametrize("engine", ["kernel", "numpy"])
def test_pieces_equal_the_whole_series(law, engine):
    """Cuts inside segments, next to rejected samples and exactly at the gap."""
    preset = "rig_truth" if law == "coulomb" else "flexiforce_8"  # rig_truth: film on
    params = load_params(preset_path(preset)).with_law(law)
    for measured_temperature in (True, False):
        t, p, temp, omega, meas, gap_at = _series(measured_temperature)
        args = (t, p, temp, omega, meas)
        whole = estimate_batch(params, *args, on_reject="skip", engine=engine)
        assert whole.reinitialised.sum() == 2 and not whole.accepted.all()
        exact = engine == "kernel" and not law.endswith("_printed")
        cuts = [1, 7, 8, 11, 12, 500, gap_at, gap_at + 2, gap_at + 3, t.size - 1]
        for capacity in (0, t.size):  # grown from nothing, or preallocated
            pieces = _stream(params, args, cuts, engine, capacity)
            _compare(whole, pieces, exact, f"{law} {engine} T={measured_temperature}")


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=4000), max_size=12, unique=True))
def test_any_cuts_give_the_same_bits_with_the_kernel(cuts):
    """Adversarial piece boundaries (hypothesis): ff_t, kernel, bit for bit."""
    params = load_params(preset_path("flexiforce_8")).with_law("ff_t")
    t, p, temp, omega, meas, _ = _series(False)
    args = tuple(x[:4001] for x in (t, p, temp, omega, meas))
    whole = estimate_batch(params, *args, on_reject="skip", engine="kernel")
    _compare(whole, _stream(params, args, cuts, "kernel", 0), True, f"cuts {sorted(cuts)}")


def test_a_wrong_continuation_would_be_seen():
    """The comparison can fail: restarting the filter and pack at a cut changes the result."""
    params = load_params(preset_path("flexiforce_8")).with_law("ff_t")
    t, p, temp, omega, meas, _ = _series(False)
    args = (t, p, temp, omega, meas)
    whole = estimate_batch(params, *args, on_reject="skip", engine="kernel")
    cut = 3000
    first = estimate_batch(params, *(x[:cut] for x in args), on_reject="skip")
    second = estimate_batch(params, *(x[cut:] for x in args), on_reject="skip")
    restarted = np.concatenate([first.modelled_torque, second.modelled_torque])
    ok = whole.accepted
    assert np.abs(restarted[ok] - whole.modelled_torque[ok]).max() > 1.0  # [N m]


def test_a_rejected_sample_raises_in_its_piece():
    params = load_params(preset_path("flexiforce_8"))
    stream = BatchEstimator(params, 4)
    stream.feed([0.0, 0.001], 1e5, math.nan, 1.0)
    with pytest.raises(OutOfOrderSample, match="sample 2"):
        stream.feed([0.0005], 1e5, math.nan, 1.0)
