"""The pack model's work-vector layout, its per-dt discretisation entry, e^{A dt} in closed form.

Kept apart from :mod:`~.pack` so the spline laws (which fill an entry's per-dt matrices)
can name these types without an import cycle.

:class:`PackModes` gives the pack's transition matrix ``Φ = e^{A dt}`` (A of
:func:`~clutch_ros.model.statespace.build_state_space`) without a matrix exponential. Every
lamella has the same mass m, stiffness k and damping c, so the damping matrix is c/k times the
stiffness matrix (proportional damping): with the chain's Laplacian ``L = Q diag(ℓ) Qᵀ``
(housing spring at the rear, free front) the modal coordinates ``q = Qᵀ z`` obey N decoupled
scalar equations ``q̈ + (c ℓ/m) q̇ + (k ℓ/m) q = …``. Each has a 2 x 2 exponential in closed
form (two real roots, a double root, or a complex pair), and
``Φ[2r+α, 2s+β] = Σ_i Q[r, i] Q[s, i] E_i[α, β]``. No expm, no balancing: a new dt costs a few
vector operations and four N x N products (~20 µs for N = 8 against ~0.2 ms for the
balanced expm), and the result is exact to rounding (the expm of the stiff matrix is accurate
to ~5e-8 of each column's scale; tests/model/test_statespace.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutch_ros.model.arraytypes import FloatArray

__all__ = ["_Entry", "_Layout", "PackModes"]


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


class PackModes:
    """``e^{A dt}`` of the lamella pack in closed form (module docstring).

    Args:
        lamella_count: N.
        mass, stiffness, damping: per lamella [kg], [N/m], [N s/m] (as ``build_state_space``).

    """

    def __init__(self, lamella_count: int, mass: float, stiffness: float,
                 damping: float) -> None:
        n = int(lamella_count)
        lap = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
        lap[-1, -1] = 1.0  # free front end (F_act side), rear end on the housing spring
        ell, self._q = np.linalg.eigh(lap)
        self.lamella_count = n
        self._a = stiffness / mass * ell  # [1/s²] per mode: q̈ + b q̇ + a q = 0
        self._b = damping / mass * ell  # [1/s]
        self._disc = self._b * self._b - 4.0 * self._a
        self._out = np.empty((n, 2, n, 2))

    def block_entries(self, dt: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Return ``(E00, E01, E10, E11)``: the entries of each mode's ``e^{A_i dt}`` (N,).

        ``A_i = [[0, 1], [−a, −b]]``, roots s1, s2 of ``s² + b s + a``. Well separated real
        roots (``|s1 − s2| dt / 2 ≥ 1``): Sylvester's formula with the two exponentials (the
        large root from the quadratic formula without cancellation, the small one as
        ``a / s1``). Otherwise ``e^{μ dt} (C I + S (A_i − μ I))``, μ = −b/2, with C, S = cosh,
        sinh(δ dt)/δ or cos, sin(ω dt)/ω (δ² = μ² − a = ±ω²), free of the 0/0 of nearly
        equal roots.
        """
        a, b, disc = self._a, self._b, self._disc
        half = 0.5 * np.sqrt(np.abs(disc))  # δ or ω
        x = half * dt
        e00, e01, e10, e11 = (np.empty_like(a) for _ in range(4))
        apart = (disc > 0.0) & (x >= 1.0)
        every = bool(apart.all())  # (the stiff pack at any dt above ~10 ns: no masking)
        if every or apart.any():
            aa, bb, hh = (a, b, half) if every else (a[apart], b[apart], half[apart])
            s1 = -0.5 * bb - hh  # the larger magnitude root
            s2 = aa / s1  # s1 s2 = a
            d = s1 - s2
            ex1, ex2 = np.exp(s1 * dt), np.exp(s2 * dt)
            phi = (ex1 - ex2) / d
            if every:
                return (s1 * ex2 - s2 * ex1) / d, phi, -aa * phi, (s1 * ex1 - s2 * ex2) / d
            e00[apart] = (s1 * ex2 - s2 * ex1) / d
            e01[apart] = phi
            e10[apart] = -aa * phi
            e11[apart] = (s1 * ex1 - s2 * ex2) / d
        near = ~apart
        if near.any():
            aa, bb, hh, xx = a[near], b[near], half[near], x[near]
            cos, sin = np.cos(xx), np.sin(xx)
            real = disc[near] > 0.0  # (there x < 1: no overflow)
            cos[real], sin[real] = np.cosh(xx[real]), np.sinh(xx[real])
            sinc = np.divide(sin, hh, out=np.full_like(xx, dt), where=hh > 0.0)  # S
            g = np.exp(-0.5 * bb * dt)
            e00[near] = g * (cos + 0.5 * bb * sinc)
            e01[near] = g * sinc
            e10[near] = -aa * g * sinc
            e11[near] = g * (cos - 0.5 * bb * sinc)
        return e00, e01, e10, e11

    def transition(self, dt: float) -> FloatArray:
        """Return ``Φ = e^{A dt}`` (2N, 2N) for ``dt`` [s], state ``[z_1, ż_1, …, z_N, ż_N]``."""
        q, out = self._q, self._out
        e = self.block_entries(dt)
        for k, (alpha, beta) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
            out[:, alpha, :, beta] = (q * e[k]) @ q.T
        n2 = 2 * self.lamella_count
        return out.reshape(n2, n2).copy()
