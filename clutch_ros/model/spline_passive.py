"""Passive ``ff_t`` and ``ff_v``: Eqs. 29-30 projected onto what spline friction can do.

Why: Eqs. 29-30 as printed (``ff_t_printed``, ``ff_v_printed`` in
:mod:`clutch_ros.model.spline`) prescribe a force whatever the lamella does. A high-pass of a
falling torque (Eq. 29) keeps pushing the plates together after a release, and a low-passed
speed (Eq. 30) lags a reversal, so the printed forces can push a lamella along its motion:
positive work on the pack, normal forces above the piston force, torque through an open clutch.
A spline friction force can do neither. It can (1) only oppose the lamella's motion, or hold it
(stick), and (2) never exceed what the spline can carry: lamella n transmits the friction torque
μ R_e (S_n + S_{n+1}) (S_{N+1} = F_act), reacted at the spline pitch radius r_s with friction
coefficient μ_s, so ``|F_fn| ≤ b_n = a (S_n + S_{n+1})``, ``a = μ μ_s R_e / r_s · |s(ω)|`` —
the bound of the ``coulomb`` law.

Derivation. Per step the force is held (zero-order hold, like ``coulomb``) and, because the
pack is linear, the positions at the end of the step are affine in it: ``z⁺ = z_free + G f``
with ``G = ∂z⁺/∂f`` symmetric negative definite (reciprocity of the damped spring chain). Let
``d`` be the printed law's force at the start of the step (``ff_t``: ``κ T − y`` with
``τ ẏ = κ T − y``; ``ff_v``: ``κ T w_n`` with ``τ ẇ_n = ż_n − w_n``; same κ, τ, Table 7). The
passive force is the one friction with "capacity d" would give: each f_n lies between 0 and the
printed force clipped to the bound,

    f_n ∈ [lo_n, hi_n],  lo_n = max(min(d_n, 0), −b_n),  hi_n = min(max(d_n, 0), b_n),

with the complementarity conditions of friction:

- interior (lo_n < f_n < hi_n): the lamella sticks, Δz_n = 0 over the step;
- f_n = hi_n: Δz_n ≥ 0 (the force, ≥ 0, opposes a compressing motion);
- f_n = lo_n: Δz_n ≤ 0.

These are exactly the KKT conditions of ``min ½ (f − f_stick)ᵀ H (f − f_stick)`` over the box
(H = −G SPD, f_stick the force that keeps every lamella where it is), so the solution exists and
is unique: the H-norm projection of the all-stuck force onto the box. Consequences:

- while the printed force lies inside the cone and opposes the motion it produces, f = d: the
  same response as Eqs. 29-30 (held over the step, like ``ff_v_printed``; ``ff_t_printed``
  integrates its decay inside the step, a difference of O(dt/τ) ≈ 1e-3 at 1 kHz);
- where the printed force would reverse the lamella (positive work), the lamella sticks with
  a smaller force instead, or, if d points the other way, slides freely (f = 0);
- ``f_n Δz_n ≥ 0`` on every lamella at every step (friction never injects energy), and
  ``|f_n| ≤ b_n``: no spline force without transmitted torque, so an open clutch releases.

Choice: the box [conv{0, clip(d)}] rather than the symmetric [−|d|, |d|] — the printed force's
direction is kept; a force is never reversed relative to what the thesis fitted. The solver is
the active-set iteration of ``coulomb`` (warm-started from the previous step's set: stuck mask,
side), with projected Gauss-Seidel as the guaranteed fallback; the small functions
:func:`box_forces` and :func:`solve_box` work on plain numpy arrays.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.arraytypes import BoolArray, FloatArray
from clutch_ros.model.laws import make_spline_law  # re-exported (defined with the registry)
from clutch_ros.model.spline import SplineLaw, WarmState

if TYPE_CHECKING:
    from clutch_ros.model.discretisation import _Entry, _Layout
    from clutch_ros.model.params import ClutchParams

__all__ = ["box_forces", "solve_box", "PassiveLaw", "PassiveTorqueFilterLaw",
           "PassiveViscousLaw", "PASSIVE_FILTER_LAWS", "make_spline_law"]

MAX_ACTIVE_SET_ITERATIONS = 64
MAX_GAUSS_SEIDEL_SWEEPS = 10000


def box_forces(g: FloatArray, f_stick: FloatArray, lo: FloatArray, hi: FloatArray,
               stuck: BoolArray, sigma: FloatArray,
               solves: dict[bytes, FloatArray] | None = None) -> FloatArray:
    """Return the forces of one active set: sliding at ``hi`` (σ > 0) or ``lo``, stuck solved.

    ``g`` (N, N) = ∂z⁺/∂f; ``f_stick`` (N,) the all-stuck force [N]; ``stuck`` boolean mask;
    ``solves`` optional cache dict of ``G_ss⁻¹ G_sl`` per stuck mask.
    """
    f = np.where(sigma > 0.0, hi, lo)
    st = np.flatnonzero(stuck)
    if st.size == 0:
        return f
    sl = np.flatnonzero(~stuck)
    if sl.size == 0:
        return f_stick.copy()
    key = stuck.tobytes()
    r = None if solves is None else solves.get(key)
    if r is None:
        r = np.linalg.solve(g[np.ix_(st, st)], g[np.ix_(st, sl)])
        if solves is not None and len(solves) < 256:
            solves[key] = r
    f[st] = f_stick[st] - r.dot(f[sl] - f_stick[sl])
    return f


def _violations(g: FloatArray, f_stick: FloatArray, f: FloatArray, lo: FloatArray,
                hi: FloatArray, stuck: BoolArray,
                sigma: FloatArray) -> tuple[BoolArray, BoolArray]:
    dz = g.dot(f - f_stick)
    scale = float(np.abs(f_stick).max()) + float((hi - lo).max()) + 1.0
    tol_f = 1e-12 * scale
    tol_z = 1e-12 * (float(np.abs(dz).max()) + 1e-15)
    bad_stuck = stuck & ((f > hi + tol_f) | (f < lo - tol_f))
    bad_slide = ~stuck & (hi > lo) & (sigma * dz < -tol_z)
    return bad_stuck, bad_slide


def solve_box(g: FloatArray, h: FloatArray, f_stick: FloatArray, lo: FloatArray,
              hi: FloatArray, stuck: BoolArray, sigma: FloatArray,
              solves: dict[bytes, FloatArray] | None = None,
              ) -> tuple[FloatArray, BoolArray, FloatArray, int]:
    """Return ``(f, stuck, sigma, iterations)``: the box projection (module docstring).

    ``h`` = −(G + Gᵀ)/2; ``stuck``/``sigma`` are the warm start (not modified). Iterations −1
    means the projected Gauss-Seidel fallback was used.
    """
    stuck, sigma = stuck.copy(), sigma.copy()
    for it in range(MAX_ACTIVE_SET_ITERATIONS):
        f = box_forces(g, f_stick, lo, hi, stuck, sigma, solves)
        bad_stuck, bad_slide = _violations(g, f_stick, f, lo, hi, stuck, sigma)
        if not (bad_stuck.any() or bad_slide.any()):
            return f, stuck, sigma, it + 1
        sigma[bad_stuck] = np.where(f[bad_stuck] > hi[bad_stuck], 1.0, -1.0)
        stuck[bad_stuck] = False
        stuck[bad_slide] = True
    f = _gauss_seidel(h, f_stick, lo, hi)
    width = hi - lo
    stuck = (f > lo + 1e-9 * width) & (f < hi - 1e-9 * width)
    sigma = np.where(f >= hi - 1e-9 * width, 1.0, -1.0)
    polished = box_forces(g, f_stick, lo, hi, stuck, sigma)
    bad_stuck, bad_slide = _violations(g, f_stick, polished, lo, hi, stuck, sigma)
    if not (bad_stuck.any() or bad_slide.any()):
        f = polished
    return f, stuck, sigma, -1


def _gauss_seidel(h: FloatArray, f_stick: FloatArray, lo: FloatArray,
                  hi: FloatArray) -> FloatArray:
    """Projected Gauss-Seidel on the box QP (converges for any SPD H)."""
    hd = np.diag(h)
    f = np.clip(f_stick, lo, hi)
    tol = 1e-13 * (float(np.abs(f_stick).max()) + 1.0)
    for _ in range(MAX_GAUSS_SEIDEL_SWEEPS):
        change = 0.0
        for i in range(f.size):
            grad = h[i].dot(f - f_stick)
            new = min(max(f[i] - grad / hd[i], lo[i]), hi[i])
            change = max(change, abs(new - f[i]))
            f[i] = new
        if change <= tol:
            break
    return f


class PassiveLaw(SplineLaw):
    """Base of the passive filter laws: printed force ``desired()`` projected per step."""

    has_force = True
    records_forces = True
    acts_per_step = True

    def __init__(self, params: ClutchParams) -> None:
        super().__init__(params)
        sp, pk = params.spline, params.pack
        self.gain = sp.gain
        self.tau = sp.time_constant
        self.coef = sp.friction_coefficient * pk.effective_radius / sp.radius
        n = self.lamella_count
        self._stuck: BoolArray = np.zeros(n, dtype=bool)
        self._sigma: FloatArray = np.ones(n)
        self.iterations = 0

    def prepare(self, entry: _Entry) -> None:
        """Stick force ``K w`` and sensitivity ``G`` at this dt (as the coulomb law's)."""
        n = self.lamella_count
        m = entry.M
        lay = entry.layout
        zrows = np.arange(0, 2 * n, 2)
        g = m[zrows][:, lay.forces]
        select = np.zeros((n, lay.head))
        select[np.arange(n), zrows] = 1.0
        entry.passive_stick = np.linalg.solve(g, select - m[zrows][:, :lay.head])
        c_ext = np.zeros((n + 1, lay.head))
        c_ext[:n, :2 * n] = entry.spring_matrix
        c_ext[n, lay.n_state] = 1.0  # F_act on the front face of lamella N
        entry.passive_normal = c_ext
        entry.passive_g = g
        entry.passive_h = -(g + g.T) / 2.0
        entry.passive_solves = {}

    @staticmethod
    def box_matrices(entry: _Entry) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Stick-force, normal-force, G and H matrices of ``entry`` (the compiled box loop)."""
        return entry.passive_stick, entry.passive_normal, entry.passive_g, entry.passive_h

    def warm_state(self) -> WarmState:
        """Active set of the last step (stuck mask, side)."""
        return (self._stuck.copy(), self._sigma.copy())

    def set_warm_state(self, value: WarmState | None) -> None:
        """Restore the active set (None: all sliding on the upper side)."""
        if value is None:
            value = (np.zeros(self.lamella_count, dtype=bool), np.ones(self.lamella_count))
        self._stuck = value[0].copy()
        self._sigma = value[1].copy()

    def desired(self, torque: float) -> FloatArray:
        """Return the printed law's force at the start of the step [N] (N,)."""
        raise NotImplementedError

    def apply(self, entry: _Entry, torque: float, mu_load: float) -> None:
        """Project the printed force onto the passive set (module docstring); write F_f.

        Per step, N = 8: the box's bounds, its sides and the check of the warm set run on
        Python floats (a dozen numpy calls on 8 elements cost more than the arithmetic); the
        products stay numpy's. The same float operations as on arrays, so the same bits.
        """
        scale = self.coef * mu_load
        des = self.desired(torque).tolist()
        if scale <= 0.0 or not any(des):
            self._f.fill(0.0)
            return
        head = self._head
        normal = entry.passive_normal.dot(head).tolist()
        hi_l, lo_l = [], []
        below = normal[0] if normal[0] > 0.0 else 0.0
        for i, d in enumerate(des):  # bound b = a (S_n + S_n+1), S >= 0; [lo, hi] of clip(d, ±b)
            above = normal[i + 1] if normal[i + 1] > 0.0 else 0.0
            b = (below + above) * scale
            below = above
            c = min(max(d, -b), b)
            hi_l.append(c if c > 0.0 else 0.0)
            lo_l.append(c if c < 0.0 else 0.0)
        f_stick = entry.passive_stick.dot(head)
        g = entry.passive_g
        stuck, sigma = self._stuck, self._sigma
        if not stuck.any():  # fast path: the previous set had every lamella sliding
            sides = sigma.tolist()
            f_l = [h if s > 0.0 else lo for h, lo, s in zip(hi_l, lo_l, sides)]
            f = np.array(f_l)
            dz = g.dot(f - f_stick).tolist()
            tol_z = -1e-12 * (max(map(abs, dz)) + 1e-15)
            if all(s * z >= tol_z or h <= lo for s, z, h, lo in zip(sides, dz, hi_l, lo_l)):
                self.iterations = 0
                self._f[:] = f
                return
        hi, lo = np.array(hi_l), np.array(lo_l)
        if stuck.any():
            f = box_forces(g, f_stick, lo, hi, stuck, sigma, entry.passive_solves)
            bad_stuck, bad_slide = _violations(g, f_stick, f, lo, hi, stuck, sigma)
            if not (bad_stuck.any() or bad_slide.any()):
                self.iterations = 0
                self._f[:] = f
                return
        f, self._stuck, self._sigma, self.iterations = solve_box(
            g, entry.passive_h, f_stick, lo, hi, stuck, sigma, entry.passive_solves)
        self._f[:] = f


class PassiveTorqueFilterLaw(PassiveLaw):
    """``ff_t``: Eq. 29's force ``κ T − y`` (τ ẏ = κ T − y) made passive (module docstring).

    κ = ``spline.gain`` [1/m, N per N m], τ = ``spline.time_constant`` [s]. The filter state
    is advanced exactly (``y⁺ = e y + (1 − e) κ T``, e = e^{−dt/τ}, T held).
    """

    name = "ff_t"
    n_states = 1
    states_scale_with_gain = True

    def fill(self, a_full: FloatArray, b_full: FloatArray, x_full: FloatArray,
             n_pack: int) -> None:
        """τ ẏ = κ T − y; the held forces enter the pack through its force columns."""
        a_full[n_pack, n_pack] = -1.0 / self.tau
        b_full[n_pack, 1] = self.gain / self.tau
        x_full[n_pack, 1] = self.gain

    def equilibrium(self, torque: float) -> FloatArray:
        """At rest y = κ T (no force)."""
        return np.array([self.gain * torque])

    def prepare(self, entry: _Entry) -> None:
        """Closed-form filter row (exact ZOH), then the projection matrices."""
        lay = entry.layout
        row = entry.M[lay.n_pack]
        row[:] = 0.0
        row[lay.n_pack] = math.exp(-entry.dt / self.tau)
        row[lay.i_torque] = -math.expm1(-entry.dt / self.tau) * self.gain
        super().prepare(entry)

    def bind(self, work: FloatArray, layout: _Layout) -> None:
        """Keep the filter state's index."""
        super().bind(work, layout)
        self._i_y = layout.n_pack
        self._buf = np.empty(self.lamella_count)

    def desired(self, torque: float) -> FloatArray:
        """κ T − y on every lamella [N]."""
        self._buf.fill(self.gain * torque - self._work.item(self._i_y))
        return self._buf


class PassiveViscousLaw(PassiveLaw):
    """``ff_v``: Eq. 30's force ``κ T w_n`` (τ ẇ_n = ż_n − w_n) made passive (module docstring).

    κ = ``spline.gain`` [s/m²], τ = ``spline.time_constant`` [s]; w_n is discretised exactly
    with the pack.
    """

    name = "ff_v"

    def __init__(self, params: ClutchParams) -> None:
        super().__init__(params)
        self.n_states = self.lamella_count

    def fill(self, a_full: FloatArray, b_full: FloatArray, x_full: FloatArray,
             n_pack: int) -> None:
        """Rows of w_n: τ ẇ_n = ż_n − w_n."""
        for i in range(self.lamella_count):
            a_full[n_pack + i, 2 * i + 1] = 1.0 / self.tau
            a_full[n_pack + i, n_pack + i] = -1.0 / self.tau

    def desired(self, torque: float) -> FloatArray:
        """κ T w_n [N]."""
        return self._s * (self.gain * torque)


#: law name -> class of the passive filter laws
PASSIVE_FILTER_LAWS = {cls.name: cls for cls in (PassiveTorqueFilterLaw, PassiveViscousLaw)}
