"""The pack model's work-vector layout and its per-dt discretisation entry (:mod:`~.pack`).

Kept apart from :mod:`~.pack` so the spline laws (which fill an entry's per-dt matrices)
can name these types without an import cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

from clutch_ros.model.arraytypes import FloatArray

__all__ = ["_Entry", "_Layout"]


@dataclass(frozen=True)
class _Layout:
    lamella_count: int
    n_pack: int
    n_state: int
    head: int
    size: int
    forces: slice
    law_states: slice
    i_force: int
    i_torque: int
    i_front: int


class _Entry:
    """Discretisation at one (quantised) dt: ``M = [Φ | Γ]`` acting on the work vector.

    The spline laws' :meth:`~clutch_ros.model.spline.SplineLaw.prepare` adds their per-dt
    matrices (declared below; only the law's own are set).
    """

    # CoulombLaw.prepare (model/spline.py)
    coulomb_stick: FloatArray
    coulomb_normal: FloatArray
    coulomb_load: FloatArray
    coulomb_g: FloatArray
    coulomb_h: FloatArray
    coulomb_hdiag: FloatArray
    coulomb_sets: dict[tuple[bytes, bytes], tuple[FloatArray, ...]]
    coulomb_blocks: dict[tuple[bytes, bytes], tuple[FloatArray, ...]]
    # PassiveLaw.prepare (model/spline_passive.py)
    passive_stick: FloatArray
    passive_normal: FloatArray
    passive_g: FloatArray
    passive_h: FloatArray
    passive_solves: dict[bytes, FloatArray]

    def __init__(self, dt: float, layout: _Layout, m: FloatArray,
                 spring_matrix: FloatArray) -> None:
        self.dt = dt
        self.layout = layout
        self.M = m
        self.spring_matrix = spring_matrix
