"""The simulated one-motor clutch rig (no ROS): truth plant, pump, thermal model, sensors, CAN.

Modules:
    pump             :class:`PumpModel` — lag, rate limit, max pressure, the pressure "kick"
    thermal          :class:`ThermalModel` — lamella heating from slip power, cooling to the oil
    flexiforce       :class:`FlexiForceArray` — 4 front + 4 rear FlexiForce voltages
    plant            :class:`RigPlant` — the truth plant producing :class:`RigSignals`
    scenario         Tables 3–4 scripted runs, closed-loop runs
    request_profile  the demo's torque-request profile (steps and ramps at 10 and 30 rpm)
    simulator        :class:`RigSimulator` — plant + scenario (+ an optional CAN port) at 1 kHz;
                     :func:`run_offline` — a run without a bus, as arrays
    can_io           :class:`RigCanPort` — DBC frames out at their cycle times, pump requests in
                     (import it from ``clutch_ros.rig.can_io``: it needs python-can, the rest of
                     the simulated rig does not)
    errors           :class:`RigError`, :class:`RigConfigError`, argument checks

The ``rig_sim`` ROS node is a thin adapter around :class:`RigSimulator`. Units are SI
(temperatures in °C) everywhere.
"""

from clutch_ros.rig.errors import RigConfigError, RigError
from clutch_ros.rig.flexiforce import FlexiForceArray, FlexiForceParams
from clutch_ros.rig.plant import NoiseParams, RigPlant, RigPlantParams, RigSignals
from clutch_ros.rig.pump import PumpModel, PumpParams
from clutch_ros.rig.scenario import (
    ClosedLoopScenario,
    Scenario,
    ScriptedScenario,
    closed_loop_run,
    table3_run,
    table4_run,
)
from clutch_ros.rig.simulator import RigSimulator, RunStats, run_offline
from clutch_ros.rig.thermal import ThermalModel, ThermalParams

__all__ = [
    "ClosedLoopScenario",
    "FlexiForceArray",
    "FlexiForceParams",
    "NoiseParams",
    "PumpModel",
    "PumpParams",
    "RigConfigError",
    "RigError",
    "RigPlant",
    "RigPlantParams",
    "RigSignals",
    "RigSimulator",
    "RunStats",
    "Scenario",
    "ScriptedScenario",
    "ThermalModel",
    "ThermalParams",
    "closed_loop_run",
    "run_offline",
    "table3_run",
    "table4_run",
]
