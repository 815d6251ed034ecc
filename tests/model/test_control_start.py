"""The start of the controller (model.control ``uncertainty_range``), on a static plant.

The plant ``T = c · C(p)`` (the capacity of Eq. 1 times the true-to-model friction ratio
``c``) has closed-form answers: before anything is learned (σ = the adaptation's prior 0.2)
the scale inverted is ``(1 + 2 σ) / 1.05 = 4/3``, so no ``c`` up to 1.4 (2 σ) gives more
than 1.05 x the request before the trim acts; the trim then reaches the exact pressure for
every ``c`` of the range (0.6 .. 1.4), from below; once learned (σ small) the start adds
nothing. The closed loop on the rig's dynamics: tests/cli/test_closed_loop_first_step.py.
"""


import pytest
from numpy.testing import assert_allclose

from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.model.inverse import capacity_scalar
from tests.model.test_control_trim import FAST, TEMP, W10, _exact, _static_loop

REQUEST = 600.0  # [N m]
PRIOR = 0.2  # [1] the adaptation's initial_std


def test_unlearned_caution_covers_two_sigma(flexiforce):
    s = ControllerSettings(**FAST)
    ctl, _ = _static_loop(flexiforce, s, REQUEST, 1.0, ticks=2, std=PRIOR, idle=5)
    assert ctl.caution == pytest.approx((1 + 2 * PRIOR) / 1.05 - 1)
    assert ctl.spread == pytest.approx(2 * PRIOR)


@pytest.mark.parametrize("c", [0.6, 0.8, 1.0, 1.2, 1.4])
def test_start_never_exceeds_the_guard_and_the_trim_reaches_the_plant(flexiforce, c):
    s = ControllerSettings(**FAST)
    ctl, outs = _static_loop(flexiforce, s, REQUEST, c, ticks=800, std=PRIOR, idle=5)
    torques = [c * capacity_scalar(flexiforce, o.pressure, TEMP, W10) for o in outs]
    delay = round(s.start_trim_delay / s.period)
    # before the trim acts: c / (4/3) of the request, at most 1.05 x (c = 1.4)
    assert_allclose(torques[delay // 2:delay], REQUEST * c / (1.4 / 1.05), rtol=1e-6)
    assert max(torques) <= 1.05 * REQUEST * (1 + 1e-6)
    assert_allclose(ctl.pressure, _exact(flexiforce, c, REQUEST), rtol=1e-6)  # no offset


def test_learned_scale_gets_no_start_margin(flexiforce):
    """σ 0.004 (a few seconds of adaptation): the margin is uncertainty_margin's 0.5 σ."""
    s = ControllerSettings(**FAST)
    ctl, _ = _static_loop(flexiforce, s, REQUEST, 1.0, ticks=2, scale=1.05, std=0.004,
                          idle=5)
    assert ctl.caution == pytest.approx(0.002, abs=1e-12)


def test_no_start_margin_without_a_measurement(flexiforce):
    s = ControllerSettings(**FAST)
    ctl, _ = _static_loop(flexiforce, s, REQUEST, 1.2, measured=False, std=PRIOR, idle=5)
    assert ctl.caution == 0.0 and ctl.spread == 0.0 and ctl.friction_scale == 1.0
