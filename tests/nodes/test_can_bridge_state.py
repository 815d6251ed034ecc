"""The can_bridge's state object and its diagnostics, without ROS processes.

The diagnostics read one :class:`BridgeState` (no module-level state): "new since the previous
report" is judged against that state's own ``reported`` counts, which ``clear()`` (configure,
cleanup) starts again; two bridges never share them.
"""

import time

from clutch_ros.canbus import PumpCommandGate, RigDatabase, RigStateAssembler
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.nodes import can_diagnostics
from clutch_ros.nodes.can_bridge_state import BridgeState
from clutch_ros.nodes.can_diagnostics import node_status


class Sources:
    """Stands in for CommandSources: no publishers on pressure_command."""

    def diagnose(self):
        return {"command_publisher_count": 0, "command_publishers": ""}


class Logger:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(("WARN", text))

    def info(self, text):
        self.lines.append(("INFO", text))


def _configure(state, db):
    """Fill ``state`` as the node's on_configure does (a log input: no bus)."""
    state.clear()
    state.last_new = time.monotonic()
    state.assembler = RigStateAssembler(db)
    state.gate = PumpCommandGate(time.monotonic, codec=state.assembler.map.pump)
    state.pacer = PublishPacer(200.0, None, frozenset(state.assembler.map.writes))
    state.lifecycle = "inactive"


def test_clear_keeps_the_node_life_fields_and_resets_the_rest():
    sources = Sources()
    state = BridgeState(sources, lifecycle="active", active=True)
    stop, reported = state.stop, state.reported
    state.published, state.lag_max, state.reported["watchdog_trips"] = 5, 0.3, 2
    state.stop.set()
    state.clear()
    assert (state.sources, state.lifecycle, state.active) == (sources, "active", True)
    assert state.published == 0 and state.lag_max == 0.0 and state.assembler is None
    assert state.reported == {} and state.reported is not reported
    assert state.stop is not stop and not state.stop.is_set()


def test_diagnostics_read_the_state_and_judge_new_counts_per_state():
    db = RigDatabase()
    logger = Logger()
    unconfigured = BridgeState(Sources())
    assert node_status(unconfigured, logger, 1.0) == (
        "OK", "unconfigured", {"lifecycle_state": "unconfigured"})

    a, b = BridgeState(Sources()), BridgeState(Sources())
    for state in (a, b):
        _configure(state, db)
        state.published, state.lag_max = 7, 0.01
        state.gate.watchdog_trips = 1
    level, message, values = node_status(a, logger, 1.0)
    assert level == "WARN" and "1 new watchdog trips" in message
    assert message.startswith("inactive; ")
    assert values["rig_state_published"] == 7 and values["watchdog_trips"] == 1
    assert values["lifecycle_state"] == "inactive" and values["receive_lag_max_s"] == 0.01
    assert a.lag_max == 0.0  # the next report covers the next period
    # the same counts again: nothing new for a; b has its own previous report (none yet)
    assert "watchdog" not in node_status(a, logger, 1.0)[1]
    assert "1 new watchdog trips" in node_status(b, logger, 1.0)[1]
    # configure again (a new gate): the counts start again, and so does "new"
    _configure(a, db)
    a.gate.watchdog_trips = 1
    assert "1 new watchdog trips" in node_status(a, logger, 1.0)[1]
    # no module-level state in the diagnostics
    assert not [name for name, value in vars(can_diagnostics).items()
                if isinstance(value, dict) and not name.startswith("__")]
