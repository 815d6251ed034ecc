"""The can_bridge node's state and counters, in one object its diagnostics read.

:class:`BridgeState` is created with the node (``__init__``), filled by ``configure`` (the
components: assembler, gate, pacer, bus or log source; the counters from zero) and cleared
by ``cleanup``. :mod:`clutch_ros.nodes.can_diagnostics` reads its public fields (and keeps
the counts of its previous report in :attr:`BridgeState.reported`); nothing else about the
bridge is shared, and nothing lives at module level.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field, fields

from clutch_ros.canbus import LogSource, PumpCommandGate, ReconnectingBus, RigStateAssembler
from clutch_ros.canbus.counters import PublishPacer
from clutch_ros.canbus.intake import CompiledIntake
from clutch_ros.nodes.command_sources import CommandSources

__all__ = ["BridgeState"]


@dataclass(eq=False)
class BridgeState:
    """What the bridge is and has done since ``configure`` (see the module docstring).

    Attributes:
        sources: who publishes ``pressure_command`` (the node's life)
        lifecycle: lifecycle state label (``unconfigured``, ``inactive``, ``active``,
            ``finalized``; the node's life)
        active: publishing rig_state and sending PumpRequests
        assembler, gate, pacer: the configured components (None while unconfigured)
        intake: the compiled intake of clean rig frames (None: ``bridge.compiled`` off, a
            log input, ``use_sim_time`` or ``bridge.publish_raw``; the Python path)
        bus: the open bus (None with a log input or unconfigured)
        source, log_thread: the log of ``input.log_file`` and its replay thread
        stop: set to stop the log replay
        published: rig_state messages published
        stale_samples: published samples with a stale signal group
        stale_groups: groups stale in the last published sample
        foreign_pump_requests: PumpRequest data frames received (another node's)
        lag_max: largest wall clock minus sample stamp at publishing since the previous
            report [s] (the diagnostics reset it)
        offset: bus time -> epoch offset [s] (None until the first frame)
        last_stamp: stamp of the last published sample [s]
        last_new: monotonic time of the last new published sample [s]
        idle_warned: the idle bus warning was logged (the diagnostics set it)
        last_report: (pressure, reason) last reported on ``pump_request``
        reported: the diagnostics' counts at their previous report

    """

    sources: CommandSources
    lifecycle: str = "unconfigured"
    active: bool = False
    assembler: RigStateAssembler | None = None
    gate: PumpCommandGate | None = None
    pacer: PublishPacer | None = None
    intake: CompiledIntake | None = None
    bus: ReconnectingBus | None = None
    source: LogSource | None = None
    log_thread: threading.Thread | None = None
    stop: threading.Event = field(default_factory=threading.Event)
    published: int = 0
    stale_samples: int = 0
    stale_groups: Sequence[str] = ()
    foreign_pump_requests: int = 0
    lag_max: float = 0.0
    offset: float | None = None
    last_stamp: float | None = None
    last_new: float = 0.0
    idle_warned: bool = False
    last_report: tuple[float, str] | None = None
    reported: dict[str, int] = field(default_factory=dict)

    #: fields kept by :meth:`clear` (they belong to the node's life, not a configuration)
    KEPT = ("sources", "lifecycle", "active")

    def clear(self) -> None:
        """Forget the configuration: no components, every counter back to its default."""
        for f in fields(self):
            if f.name not in self.KEPT:
                setattr(self, f.name, f.default_factory() if f.default_factory is not MISSING
                        else f.default)
