"""Spline-friction laws behind one interface: ``none``, ``coulomb`` and Eqs. 29-30 as printed.

The passive ``ff_t`` and ``ff_v`` (the presets' laws) are in
:mod:`clutch_ros.model.spline_passive`;
this module keeps Eqs. 29-30 exactly as printed as ``ff_t_printed`` and ``ff_v_printed``. They
are NOT passive: a high-pass of a falling torque (Eq. 29) or a filtered speed that lags a
reversal (Eq. 30) pushes lamellas along their motion, so friction can do positive work on the
pack (normal forces above the piston force, torque through an open clutch). They are kept for
reproducing the thesis only and are never a default.

A law supplies the per-lamella spline friction force ``F_fn`` [N] that Eqs. 11-13 subtract
(positive = opposing compression). :class:`~clutch_ros.model.pack.PackModel` holds the force
constant over each step (zero-order hold) and calls the law once per step, before advancing.
The torque a law sees, ``T``, is the magnitude of the torque the pack transmits at the start of
the step, ``2 R_e μ |s(ω)| Σ S_n`` [N m] (spline load grows with transmitted torque; s is the
regularised torque sign of :mod:`clutch_ros.model.friction`, μ the pack-state μ).

Laws with dynamics append states to the pack state, so the whole (pack + law) system is one
linear ODE between samples and is discretised exactly by the pack's matrix exponential:

- ``none``: F_f = 0 (the Eq. 1 pack).
- ``ff_t_printed`` (Eq. 29): ``F_f = τs/(τs+1) κ T``, the same force on every lamella. State ``y``
  with ``τ ẏ = κ T − y`` and ``F_f = κ T − y``; T is held over the step and the force
  ``κ T − y(t)`` enters the pack's equations inside the step, so pack and filter are
  discretised together exactly: the response to a torque step is ``κ T e^{−t/τ}`` at every
  sample, for any (variable) dt. κ = ``spline.gain`` [1/m] (N per N m), τ [s].
- ``ff_v_printed`` (Eq. 30): ``F_fn = T κ 1/(τs+1) ż_n``. States ``w_n`` with ``τ ẇ_n = ż_n − w_n``
  integrated exactly with the pack (the filter sees the true ż inside the step);
  ``F_fn = κ T w_n`` is evaluated at the start of the step and held (the product of T and
  w would make the step matrix depend on T). Exact filter, force held: accurate for
  dt ≪ τ (1 ms against 2 s). κ = ``spline.gain`` [s/m² = N per (N m · m/s)], τ [s].
- ``coulomb``: physical spline friction with stiction. Lamella n carries μ R_e (S_n + S_{n+1})
  of friction torque (S_{N+1} = F_act), reacted at the spline radius r_s, so the axial friction
  is bounded by ``|F_fn| ≤ a (S_n + S_{n+1})`` with ``a = μ μ_s R_e / r_s · |s(ω)|``
  (μ_s = ``spline.friction_coefficient``, r_s = ``spline.radius``). While a plate slides in
  compression the quasi-static force ratio is ``S_n / S_{n+1} = (1 − a)/(1 + a)``, reversed
  on rebound: a persistent hysteresis.

Coulomb numerics (time stepping in the style of Moreau): after one ZOH step the positions are
affine in the held friction vector, ``z⁺ = z_free + G f``. The law finds the ``f`` for which
every stuck lamella ends the step where it started (``z⁺_n = z_n``) while ``|f_n| ≤ b_n``,
and every sliding lamella gets ``f_n = ±b_n`` opposing its displacement over the step. This
is the H-norm projection of the all-stuck force onto the box |f| ≤ b (H = −G, symmetric
positive definite), so the solution is unique; it is found by an active-set iteration
warm-started from the previous step (fast path: the previous set still holds, typically all
stuck or all sliding), with projected Gauss-Seidel as a guaranteed fallback. Bounds use the
forces at the start of the step. Friction never injects energy (F_fn Δz_n ≥ 0 on every
lamella) and the scheme does not depend on dt.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model.arraytypes import BoolArray, FloatArray

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.discretisation import _Entry, _Layout
    from clutch_ros.model.params import ClutchParams

#: a law's active set: stuck mask and slide sides (σ = ±1)
WarmState = tuple[BoolArray, FloatArray]

__all__ = ["SplineLaw", "NoSplineFriction", "TorqueFilterLaw", "ViscousLaw", "CoulombLaw"]


class SplineLaw:
    """Interface of a spline-friction law (also the ``none`` law: no force, no state).

    Attributes:
        name: law name as in ``spline.law``.
        n_states: number of law states appended to the pack state.
        has_force: False if the law never produces a force (lets callers skip work).

    The pack builds the continuous system with state ``[x (2N), law states]`` and input
    ``[F_act, T, F_f1..F_fN]``; :meth:`fill` adds the law's rows. Per step the pack writes
    F_act and T into its work vector and calls :meth:`apply`, which writes the held forces.

    """

    name = "none"
    n_states = 0
    has_force = False
    records_forces = False  # True: simulate() must record the forces per step
    acts_per_step = False  # True: apply() does work before every step
    states_scale_with_gain = False  # True: the states are κ times a gain-free filter

    def __init__(self, params: ClutchParams) -> None:
        self.params = params
        self.lamella_count = params.pack.lamella_count

    def fill(self, a_full: FloatArray, b_full: FloatArray, x_full: FloatArray,
             n_pack: int) -> None:
        """Add the law's rows to the continuous (A, B) and static-gain matrices."""

    def prepare(self, entry: _Entry) -> None:
        """Precompute per-dt quantities on the cache ``entry`` (has ``M``, ``dt``)."""

    def bind(self, work: FloatArray, layout: _Layout) -> None:
        """Keep views into the pack's work vector (``layout`` gives the slices)."""
        self._work = work
        self._f = work[layout.forces]
        self._s = work[layout.law_states]
        self._head = work[:layout.head]

    def equilibrium(self, torque: float) -> FloatArray:
        """Return the law states at rest under a constant torque T [N m]."""
        return np.zeros(self.n_states)

    def apply(self, entry: _Entry, torque: float, mu_load: float) -> None:
        """Write the forces held over the next step into the work vector.

        ``torque`` is T [N m] at the start of the step; ``mu_load`` = μ |s(ω)|.
        """

    def current_forces(self) -> FloatArray:
        """Return the spline forces of the last step, rear → front [N] (a copy)."""
        return self._f.copy()

    def forces_series(self, prev_states: FloatArray, states: FloatArray,
                      torque: FloatArray) -> FloatArray:
        """Return what :meth:`current_forces` gives after steps 1..n-1 (vectorised).

        ``prev_states``/``states``: law states before/after each step (n-1, n_states);
        ``torque``: T of each step (n-1,).
        """
        return np.zeros((torque.size, self.lamella_count))

    def warm_state(self) -> WarmState | None:
        """Return the law's non-vector state (for snapshots); None if it has none."""
        return None

    def set_warm_state(self, value: WarmState | None) -> None:
        """Restore what :meth:`warm_state` returned."""


NoSplineFriction = SplineLaw


class TorqueFilterLaw(SplineLaw):
    """``ff_t_printed``, Eq. 29 as printed: high-passed torque on every lamella (not passive).

    The force ``κ T − y(t)`` enters the pack's continuous equations directly (T held over the
    step), so the ZOH of the combined system is exact: F_f decays inside a step just as the
    transfer function says, whatever dt. :meth:`current_forces` reports it at the end of the
    step.
    """

    name = "ff_t_printed"
    n_states = 1
    has_force = True
    states_scale_with_gain = True

    def __init__(self, params: ClutchParams) -> None:
        super().__init__(params)
        self.gain = params.spline.gain
        self.tau = params.spline.time_constant

    def fill(self, a_full: FloatArray, b_full: FloatArray, x_full: FloatArray,
             n_pack: int) -> None:
        """τ ẏ = κ T − y, and every lamella feels −(κ T − y); at rest y = κ T, no force."""
        a_full[n_pack, n_pack] = -1.0 / self.tau
        b_full[n_pack, 1] = self.gain / self.tau
        x_full[n_pack, 1] = self.gain
        each = b_full[:n_pack, 2:].sum(axis=1)  # B column of a force on every lamella
        a_full[:n_pack, n_pack] = -each
        b_full[:n_pack, 1] = self.gain * each
        b_full[:, 2:] = 0.0  # the held-force inputs are unused by this law
        x_full[:, 2:] = 0.0

    def equilibrium(self, torque: float) -> FloatArray:
        """At rest y = κ T (no force)."""
        return np.array([self.gain * torque])

    def prepare(self, entry: _Entry) -> None:
        """Write the filter row in closed form: y⁺ = e y + (1 − e) κ T, e = e^{−dt/τ}.

        The row does not depend on the pack, so this is the exact ZOH; the expm of the whole
        stiff matrix would carry its ~1e-8 relative error into the filter.
        """
        lay = entry.layout
        row = entry.M[lay.n_pack]
        decay = math.exp(-entry.dt / self.tau)
        row[:] = 0.0
        row[lay.n_pack] = decay
        row[lay.i_torque] = -math.expm1(-entry.dt / self.tau) * self.gain

    def bind(self, work: FloatArray, layout: _Layout) -> None:
        """Also keep the index of T."""
        super().bind(work, layout)
        self._i_torque = layout.i_torque

    def current_forces(self) -> FloatArray:
        """F_f = κ T − y at the end of the last step, on every lamella [N]."""
        return np.full(self.lamella_count,
                       self.gain * self._work[self._i_torque] - self._s[0])

    def forces_series(self, prev_states: FloatArray, states: FloatArray,
                      torque: FloatArray) -> FloatArray:
        """Vectorised :meth:`current_forces`."""
        f = self.gain * torque - states[:, 0]
        return np.repeat(f[:, None], self.lamella_count, axis=1)

    @staticmethod
    def step_response(gain: float, tau: float, torque: float, t: ArrayLike) -> FloatArray:
        """Return the force after a torque step 0 → T at t = 0: κ T e^{−t/τ} [N] (closed form)."""
        return gain * torque * np.exp(-np.asarray(t, dtype=float) / tau)


class ViscousLaw(SplineLaw):
    """``ff_v_printed``, Eq. 30 as printed: torque times low-passed lamella speed (not passive)."""

    name = "ff_v_printed"
    has_force = True
    acts_per_step = True

    def __init__(self, params: ClutchParams) -> None:
        super().__init__(params)
        self.gain = params.spline.gain
        self.tau = params.spline.time_constant
        self.n_states = self.lamella_count

    def fill(self, a_full: FloatArray, b_full: FloatArray, x_full: FloatArray,
             n_pack: int) -> None:
        """Rows of w_n: τ ẇ_n = ż_n − w_n."""
        for i in range(self.lamella_count):
            a_full[n_pack + i, 2 * i + 1] = 1.0 / self.tau
            a_full[n_pack + i, n_pack + i] = -1.0 / self.tau

    def apply(self, entry: _Entry, torque: float, mu_load: float) -> None:
        """F_fn = κ T w_n."""
        np.multiply(self._s, self.gain * torque, out=self._f)

    def forces_series(self, prev_states: FloatArray, states: FloatArray,
                      torque: FloatArray) -> FloatArray:
        """Vectorised :meth:`apply` (same float operations)."""
        return prev_states * (self.gain * torque)[:, None]


class CoulombLaw(SplineLaw):
    """``coulomb``: spline stiction bounded by a (S_n + S_{n+1}) (module docstring)."""

    name = "coulomb"
    has_force = True
    records_forces = True
    acts_per_step = True
    max_active_set_iterations = 64
    max_gauss_seidel_sweeps = 10000

    def __init__(self, params: ClutchParams) -> None:
        super().__init__(params)
        sp, pk = params.spline, params.pack
        #: a = coef · μ |s(ω)|
        self.coef = sp.friction_coefficient * pk.effective_radius / sp.radius
        n = self.lamella_count
        self._stuck: BoolArray = np.ones(n, dtype=bool)
        self._sigma: FloatArray = np.ones(n)
        self._mats_entry: _Entry | None = None
        self._mats: tuple[FloatArray, ...] | None = None
        self.iterations = 0  # active-set iterations of the last step (diagnostics)

    def prepare(self, entry: _Entry) -> None:
        """Stick-force and position-sensitivity matrices for this dt."""
        n = self.lamella_count
        m = entry.M
        nx, head = entry.layout.n_state, entry.layout.head
        zrows = np.arange(0, 2 * n, 2)
        g = m[zrows][:, entry.layout.forces]  # dz+/df (N, N)
        select = np.zeros((n, head))
        select[np.arange(n), zrows] = 1.0
        k_stick = np.linalg.solve(g, select - m[zrows][:, :head])  # f_stick = K w_head
        c_ext = np.zeros((n + 1, head))
        c_ext[:n, :2 * n] = entry.spring_matrix
        c_ext[n, nx] = 1.0  # F_act, the force on the front face of lamella N
        entry.coulomb_stick = k_stick
        entry.coulomb_normal = c_ext  # rows: S_1..S_N, F_act
        entry.coulomb_load = c_ext[:n] + c_ext[1:]  # S_n + S_{n+1} (bound / a, unclamped)
        entry.coulomb_g = g
        h = -(g + g.T) / 2.0
        entry.coulomb_h = h
        entry.coulomb_hdiag = np.diag(h).copy()
        entry.coulomb_sets = {}
        entry.coulomb_blocks = {}

    @staticmethod
    def box_matrices(entry: _Entry) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Stick-force, normal-force, G and H matrices of ``entry`` (the compiled box loop)."""
        return entry.coulomb_stick, entry.coulomb_normal, entry.coulomb_g, entry.coulomb_h

    def bind(self, work: FloatArray, layout: _Layout) -> None:
        """Also keep the index of F_act and the [1, a] mixing vector."""
        super().bind(work, layout)
        self._i_force = layout.i_force
        self._mix = np.array([1.0, 0.0])

    def warm_state(self) -> WarmState:
        """Active set of the last step (stuck mask, slide directions)."""
        return (self._stuck.copy(), self._sigma.copy())

    def set_warm_state(self, value: WarmState | None) -> None:
        """Restore the active set."""
        if value is None:
            value = (np.ones(self.lamella_count, dtype=bool), np.ones(self.lamella_count))
        self._stuck = value[0].copy()
        self._sigma = value[1].copy()
        self._mats_entry = None

    def _set_matrices(self, entry: _Entry, stuck: BoolArray,
                      sigma: FloatArray) -> tuple[FloatArray, ...]:
        """Fused kernel of one active set (stuck mask, slide signs) at one dt.

        With ``y = [f_stick; b]``, ``f_stick = K w``, ``b = a L w`` (w = work head): the
        forces are ``f = F y`` and the set is valid iff ``C y ≥ 0`` (stuck: ``b ∓ f ≥ 0``;
        sliding: the displacement over the step has the sign of its force) and every
        ``S_n ≥ 0``. All are linear in ``w`` with a factor 1 or ``a``, so one matrix ``Z``
        gives ``[[P], [Q]] = Z w`` and ``[conditions; forces] = P + a Q``.
        """
        key = (stuck.tobytes(), sigma.tobytes())
        mats = entry.coulomb_sets.get(key)
        if mats is not None:
            return mats
        n = self.lamella_count
        eye = np.eye(n)
        a1 = np.zeros((n, n))
        a2 = np.zeros((n, n))
        st, sl = np.flatnonzero(stuck), np.flatnonzero(~stuck)
        a2[sl, sl] = sigma[sl]
        g = entry.coulomb_g
        if st.size:
            a1[st, st] = 1.0
            if sl.size:
                r = np.linalg.solve(g[np.ix_(st, st)], g[np.ix_(st, sl)])
                a1[np.ix_(st, sl)] = r
                a2[np.ix_(st, sl)] = -r * sigma[sl]
        dz1, dz2 = g @ (a1 - eye), g @ a2  # displacement over the step = dz1 f_stick + dz2 b
        rows1: list[FloatArray] = []
        rows2: list[FloatArray] = []
        for i in st:
            rows1 += [-a1[i], a1[i]]  # b - f >= 0, b + f >= 0
            rows2 += [eye[i] - a2[i], eye[i] + a2[i]]
        for i in sl:
            rows1.append(sigma[i] * dz1[i] / entry.coulomb_hdiag[i])  # moves against F_f
            rows2.append(sigma[i] * dz2[i] / entry.coulomb_hdiag[i])
        k_stick, load = entry.coulomb_stick, entry.coulomb_load
        p_part = np.vstack([np.array(rows1) @ k_stick, entry.coulomb_normal[:n], a1 @ k_stick])
        q_part = np.vstack([np.array(rows2) @ load, np.zeros((n, load.shape[1])), a2 @ load])
        n_cond = len(rows1) + n
        out2d = np.empty((2, n_cond + n))
        res = np.empty(n_cond + n)
        mats = (np.vstack([p_part, q_part]), out2d, out2d.reshape(-1), res, res[:n_cond],
                res[n_cond:])
        if len(entry.coulomb_sets) < 64:
            entry.coulomb_sets[key] = mats
        return mats

    def block_kernel(self, entry: _Entry) -> tuple[FloatArray, ...]:
        """Step map and checks of the current active set at ``entry`` (for batch runs).

        Returns ``(Z, P_c, Q_c, P_f, Q_f)`` on the work vector ``r = [w, F_f]`` (w = work
        head): while the set holds, the state after the step is ``Z[:nx] r + a Z[nx:] r``
        (the forces are folded in, so ``F_f`` in ``r`` is ignored), the set's conditions
        (:meth:`_set_matrices`) are ``P_c w + a Q_c w`` and the forces ``P_f w + a Q_f w``.
        """
        key = (self._stuck.tobytes(), self._sigma.tobytes())
        kern = entry.coulomb_blocks.get(key)
        if kern is not None:
            return kern
        zmat = self._set_matrices(entry, self._stuck, self._sigma)[0]
        n = self.lamella_count
        lay = entry.layout
        half = zmat.shape[0] // 2
        n_cond = half - n
        p_part, q_part = zmat[:half], zmat[half:]
        m = entry.M
        nx, head = lay.n_state, lay.head
        gamma_f = m[:, lay.forces]
        z = np.zeros((2 * nx, lay.size))
        z[:nx, :head] = m[:, :head] + gamma_f @ p_part[n_cond:]
        z[nx:, :head] = gamma_f @ q_part[n_cond:]
        kern = (z, p_part[:n_cond].copy(), q_part[:n_cond].copy(), p_part[n_cond:].copy(),
                q_part[n_cond:].copy())
        if len(entry.coulomb_blocks) < 64:
            entry.coulomb_blocks[key] = kern
        return kern

    def apply(self, entry: _Entry, torque: float, mu_load: float) -> None:
        """Solve the stick/slip step; write F_f (module docstring)."""
        scale = self.coef * mu_load
        if scale <= 0.0:  # no transmitted torque, no spline load: frictionless
            self._f.fill(0.0)
            return
        self.iterations = 0
        mats = self._mats
        if self._mats_entry is not entry or mats is None:  # (set together)
            mats = self._mats = self._set_matrices(entry, self._stuck, self._sigma)
            self._mats_entry = entry
        zmat, out2d, out_flat, res, cond, forces = mats
        np.dot(zmat, self._head, out=out_flat)
        self._mix[1] = scale
        np.dot(self._mix, out2d, out=res)
        if min(cond.tolist()) >= -1e-9 * (self._work[self._i_force] + 1.0):
            self._f[:] = forces  # the previous active set still holds
            return
        head = self._head
        normal = np.maximum(entry.coulomb_normal.dot(head), 0.0)
        bound = (normal[:-1] + normal[1:]) * scale
        self._f[:] = self._solve(entry, entry.coulomb_stick.dot(head), bound)

    @staticmethod
    def _forces(entry: _Entry, f_stick: FloatArray, bound: FloatArray, stuck: BoolArray,
                sigma: FloatArray) -> FloatArray:
        f = sigma * bound
        st = np.flatnonzero(stuck)
        if st.size == 0:
            return f
        sl = np.flatnonzero(~stuck)
        if sl.size == 0:
            return f_stick.copy()
        g = entry.coulomb_g
        rhs = g[np.ix_(st, sl)].dot(f[sl] - f_stick[sl])
        f[st] = f_stick[st] - np.linalg.solve(g[np.ix_(st, st)], rhs)
        return f

    def _solve(self, entry: _Entry, f_stick: FloatArray, bound: FloatArray) -> FloatArray:
        stuck = self._stuck.copy()
        sigma = self._sigma.copy()
        scale = float(np.abs(f_stick).max()) + float(bound.max()) + 1.0
        tol_f = 1e-12 * scale
        for it in range(self.max_active_set_iterations):
            f = self._forces(entry, f_stick, bound, stuck, sigma)
            dz = entry.coulomb_g.dot(f - f_stick)
            tol_z = 1e-12 * (float(np.abs(dz).max()) + 1e-15)
            bad_stuck = stuck & (np.abs(f) > bound + tol_f)
            bad_slide = ~stuck & (bound > 0.0) & (sigma * dz < -tol_z)
            if not (bad_stuck.any() or bad_slide.any()):
                self.iterations = it + 1
                self._remember(stuck, sigma)
                return f
            sigma[bad_stuck] = np.where(f[bad_stuck] < 0.0, -1.0, 1.0)
            stuck[bad_stuck] = False
            stuck[bad_slide] = True
        f = self._gauss_seidel(entry, f_stick, bound)
        self.iterations = -1
        stuck = np.abs(f) < bound * (1.0 - 1e-9)
        sigma = np.where(f < 0.0, -1.0, 1.0)
        self._remember(stuck, sigma)
        return f

    def _gauss_seidel(self, entry: _Entry, f_stick: FloatArray,
                      bound: FloatArray) -> FloatArray:
        """Projected Gauss-Seidel on the box QP, then polished on its active set.

        PGS converges for any symmetric positive definite H; the active set it identifies
        is then solved exactly (same linear algebra as the active-set path) and kept if
        consistent, so both paths give the same solution to rounding.
        """
        h, hd = entry.coulomb_h, entry.coulomb_hdiag
        f = np.clip(f_stick, -bound, bound)
        tol = 1e-13 * (float(np.abs(f_stick).max()) + 1.0)
        for _ in range(self.max_gauss_seidel_sweeps):
            change = 0.0
            for i in range(f.size):
                g = h[i].dot(f - f_stick)
                new = min(max(f[i] - g / hd[i], -bound[i]), bound[i])
                change = max(change, abs(new - f[i]))
                f[i] = new
            if change <= tol:
                break
        stuck = np.abs(f) < bound * (1.0 - 1e-6)
        sigma = np.where(f < 0.0, -1.0, 1.0)
        polished = self._forces(entry, f_stick, bound, stuck, sigma)
        dz = entry.coulomb_g.dot(polished - f_stick)
        scale = float(np.abs(f_stick).max()) + float(bound.max()) + 1.0
        ok = (np.all(np.abs(polished[stuck]) <= bound[stuck] + 1e-9 * scale)
              and np.all(sigma[~stuck] * dz[~stuck] >= -1e-12 * (np.abs(dz).max() + 1e-15)))
        return polished if ok else f

    def _remember(self, stuck: BoolArray, sigma: FloatArray) -> None:
        self._stuck = stuck
        self._sigma = sigma
        self._mats_entry = None


