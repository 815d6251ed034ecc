"""The controller's settings refuse values out of their ranges, naming the setting."""

import math

import pytest

from clutch_ros.model.controller_settings import ControllerSettings
from clutch_ros.model.errors import ModelError


@pytest.mark.parametrize("name", ["uncertainty_range", "start_trim_delay"])
def test_start_settings_must_not_be_negative(name):
    with pytest.raises(ModelError, match=name):
        ControllerSettings(**{name: -0.1})
    with pytest.raises(ModelError, match=name):
        ControllerSettings(**{name: math.nan})


def test_uncertainty_margin_must_not_be_negative():
    with pytest.raises(ModelError, match="uncertainty_margin"):
        ControllerSettings(uncertainty_margin=-0.1)
