"""Closed-form references shared by the model tests (independent of the model code)."""

import numpy as np


def modal_phi(n, m, k, c, dt):
    """Return e^{A dt} of the pack in closed form.

    Equal m, k, c make the damping proportional to the stiffness, so the chain's Laplacian
    modes decouple into scalar 2nd-order systems with exact formulas.
    """
    lap = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    lap[-1, -1] = 1.0  # free front end (F_act side), fixed rear end (housing spring)
    lam, q = np.linalg.eigh(lap)
    blocks = np.zeros((2 * n, 2 * n))
    for j in range(n):
        damp, stiff = c / m * lam[j], k / m * lam[j]
        root = np.sqrt(damp * damp - 4 * stiff)
        s_fast = (-damp - root) / 2
        s_slow = 2 * stiff / (-damp - root)  # s_fast * s_slow = stiff, no cancellation
        e_f, e_s = np.exp(s_fast * dt), np.exp(s_slow * dt)
        c0 = (s_fast * e_s - s_slow * e_f) / (s_fast - s_slow)
        c1 = (e_f - e_s) / (s_fast - s_slow)
        # ż from ż: c0 − damp c1 written out, (s_f e_f − s_s e_s) / (s_f − s_s), as c0 − damp c1
        # cancels to ~1e-8 relative on a stiff pack
        c3 = (s_fast * e_f - s_slow * e_s) / (s_fast - s_slow)
        idx = [j, n + j]
        blocks[np.ix_(idx, idx)] = np.array([[c0, c1], [-stiff * c1, c3]])
    t = np.kron(np.eye(2), q)
    full = t @ blocks @ t.T  # ordered [z; v]
    perm = np.empty(2 * n, dtype=int)
    perm[0::2], perm[1::2] = np.arange(n), n + np.arange(n)
    return full[np.ix_(perm, perm)]


def step_response_positions(n, m, k, c, force, t):
    """z_n(t) [m] of the pack at rest at t = 0 under a force step ``force`` [N] on lamella N.

    x(t) = X F + e^{A t} (x(0) − X F) with the series-spring equilibrium z_n = n F / k and the
    modal closed form of e^{A t}.
    """
    x_eq = np.zeros(2 * n)
    x_eq[0::2] = np.arange(1, n + 1) * force / k
    return np.array([(x_eq - modal_phi(n, m, k, c, ti) @ x_eq)[0::2] for ti in np.atleast_1d(t)])
