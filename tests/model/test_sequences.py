"""Tables 3 and 4 as time series: durations, levels, steps, slip directions."""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.model import InputError, make_sequence, rpm_to_rad_s, table3, table4
from clutch_ros.model.sequences import BAR, SEQUENCE_NAMES, ramp_sequence

WINDOWS = {"step": 10.0, "inc_step": 24.0, "ramp4": 4.0, "ramp12": 12.0, "ramp24": 24.0,
           "pbd": 10.0}


@pytest.mark.parametrize("name", SEQUENCE_NAMES)
def test_windows_levels_and_grid(name):
    seq = make_sequence(name, 30.0, 1e-3)
    start, end = seq.active
    assert_allclose(end - start, WINDOWS[name], rtol=1e-12)  # Tables 3-4 "Time [s]"
    assert_allclose(np.diff(seq.t), 1e-3, rtol=1e-9)
    assert seq.actuating_pressure.max() == pytest.approx(40 * BAR, rel=1e-12)
    assert seq.actuating_pressure[0] == 0.0 and seq.actuating_pressure[-1] == 0.0  # leads
    inside = (seq.t > start + 1e-9) & (seq.t <= end + 1e-9)
    assert np.all(seq.actuating_pressure[~inside] == 0.0)  # 0 bar outside the window
    assert np.all(seq.lamella_temperature == 35.0)


def test_incremented_step_has_eight_steps_of_10_bar():
    seq = make_sequence("inc_step", 10.0, 1e-3)
    jumps = np.diff(seq.actuating_pressure)
    jumps = jumps[jumps != 0.0]
    assert jumps.size == 8
    assert_allclose(np.abs(jumps), 10 * BAR, rtol=1e-12)
    assert list(np.sign(jumps)) == [1, 1, 1, 1, -1, -1, -1, -1]
    assert np.all(seq.slip_speed == rpm_to_rad_s(10.0))  # DBP: slip before pressure


def test_ramp_is_a_triangle():
    seq = ramp_sequence(24.0, 10.0, 1e-3)
    k = int(np.argmax(seq.actuating_pressure))
    assert_allclose(seq.t[k], seq.active[0] + 12.0, atol=1e-9)
    assert_allclose(np.diff(seq.actuating_pressure[k - 5000:k]).max(), 40 * BAR / 12e3,
                    rtol=1e-9)
    held = ramp_sequence(24.0, 10.0, 1e-3, hold_at=(20 * BAR,), hold_time=5.0)
    assert_allclose(held.active[1] - held.active[0], 34.0, rtol=1e-12)
    assert np.count_nonzero(held.actuating_pressure == 20 * BAR) >= 2 * 5000
    with pytest.raises(InputError):
        ramp_sequence(4.0, hold_at=(50 * BAR,), hold_time=1.0)


def test_pbd_pressure_before_positive_then_negative_slip():
    seq = make_sequence("pbd", 30.0, 1e-3, temperature=60.0)
    w = seq.slip_speed
    on = seq.actuating_pressure > 0
    assert np.all(w[~on] == 0.0)  # pressure before delta
    first_pos = np.argmax(w > 0)
    first_neg = np.argmax(w < 0)
    assert 0 < first_pos < first_neg and on[first_pos] and on[first_neg]
    assert w.max() == rpm_to_rad_s(30.0) == -w.min()
    assert np.all(seq.lamella_temperature == 60.0)


def test_tables():
    assert [s.name for s in table3(50.0)] == list(SEQUENCE_NAMES[:5])
    assert [(s.slip_rpm, s.lamella_temperature[0]) for s in table4()] == [
        (10.0, 35.0), (10.0, 60.0), (30.0, 35.0), (30.0, 60.0)]
    with pytest.raises(InputError):
        make_sequence("ramp5")


def test_pbd_release_applies_at_standstill_and_releases_while_slipping():
    seq = make_sequence("pbd_release", 10.0, 1e-3)
    w = rpm_to_rad_s(10.0)
    start, end = seq.active
    on = (seq.t > start + 1e-9) & (seq.t <= end + 1e-9)
    assert np.all(seq.actuating_pressure[on] == 30 * BAR)
    assert np.all(seq.actuating_pressure[~on] == 0.0)
    # standstill for the first second under pressure, +w, a 0.5 s stop, -w until the end
    assert np.all(seq.slip_speed[on & (seq.t <= start + 1.0)] == 0.0)
    levels = [v for i, v in enumerate(seq.slip_speed) if i == 0 or v != seq.slip_speed[i - 1]]
    assert levels == [0.0, w, 0.0, -w]
    stop = seq.t[(seq.slip_speed == 0.0) & on & (seq.t > start + 1.5)]
    assert_allclose(stop[-1] - stop[0], 0.5 - 1e-3, atol=1e-9)
    assert seq.slip_speed[-1] == -w  # still slipping after the release
