"""ThermalModel: closed-form lamella response, coupled steady state, plausible heating."""

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from clutch_ros.rig.errors import RigConfigError
from clutch_ros.rig.thermal import ThermalModel, ThermalParams


def test_lamella_first_order_closed_form_with_fixed_oil():
    params = ThermalParams(oil_heat_capacity=math.inf)
    model = ThermalModel(params)
    model.reset(lamella_temperature=50.0, oil_temperature=40.0)
    power, dt = 3000.0, 1e-2
    out = np.array([model.step(dt, power) for _ in range(15000)])  # 150 s = 6 tau
    t = dt * np.arange(1, 15001)
    tau = params.lamella_time_constant  # C/G = 25 s
    steady = 40.0 + power / params.lamella_to_oil_conductance  # P/G + T_oil = 90 degC
    expected = steady + (50.0 - steady) * np.exp(-t / tau)
    # exact exponential update with the oil held: float round-off only
    assert_allclose(out[:, 0], expected, rtol=1e-10)
    assert_allclose(out[:, 1], 40.0)
    assert params.steady_lamella_temperature(power, 40.0) == pytest.approx(steady)


def test_steady_state_equals_power_over_conductance_plus_oil():
    params = ThermalParams()
    model = ThermalModel(params)
    power = 1200.0
    for _ in range(20000):  # dt 1 s: 20000 s >> the slow (oil) time constant of ~10 min
        lam, oil = model.step(1.0, power)
    # coupled fixed point: T_oil = T_amb + P/G_a, T_lamella = T_oil + P/G
    assert oil == pytest.approx(params.ambient_temperature + power / 40.0, abs=1e-6)
    assert lam == pytest.approx(oil + power / params.lamella_to_oil_conductance, abs=1e-6)


def test_plausible_heating_at_40_bar_50_rpm():
    model = ThermalModel()
    power = 1400.0 * 50 * 2 * math.pi / 60  # ~1.4 kN m at 50 rpm: ~7.3 kW
    temps = [model.step(1e-3, power)[0] for _ in range(20000)]
    assert temps[0] == pytest.approx(35.0, abs=0.01)
    assert 90.0 < temps[-1] < 150.0  # tens of seconds to ~100 degC, as in the thesis
    assert model.oil_temperature < 40.0  # the oil warms much more slowly
    for _ in range(200000):  # 200 s without slip: cooling back towards the oil
        model.step(1e-3, 0.0)
    assert model.lamella_temperature < 45.0


def test_invalid_inputs_raise():
    model = ThermalModel()
    with pytest.raises(RigConfigError):
        model.step(1e-3, -1.0)
    with pytest.raises(RigConfigError):
        model.step(1e-3, math.nan)
    with pytest.raises(RigConfigError):
        model.step(0.0, 1.0)
    with pytest.raises(RigConfigError):
        ThermalParams(lamella_heat_capacity=0.0)
    with pytest.raises(RigConfigError):
        ThermalParams(ambient_temperature=math.nan)
