"""State-space form of the N-lamella pack (Eqs. 11-26) and its exact ZOH discretisation.

Numbering as in the text of thesis 6.1 (Eqs. 11-13 and 27): lamella 1 is the rear one,
supported by the housing spring ``k z_1``; lamella N is the front one, where
``F_act = p · A`` acts. For every lamella n (``z_0 = 0``; the term in braces only for n < N)::

    m z̈_n = {k (z_{n+1} − z_n) + c (ż_{n+1} − ż_n)} − k (z_n − z_{n−1}) − c (ż_n − ż_{n−1})
            − F_fn + [n = N] F_act

State ``x = [z_1, ż_1, z_2, ż_2, …, z_N, ż_N]`` (Eqs. 14-19) [m, m/s]; input
``u = [F_act, F_f1, …, F_fN]`` [N] (Eq. 20-21 with one column per lamella; a positive F_fn
opposes compression). Note: the matrices printed as Eqs. 24-25 for N = 3 number the lamellas
the other way round (F_act enters lamella 1 and the housing spring sits at lamella 3); they are
the mirror image of Eqs. 11-13. This module follows Eqs. 11-13; the tests check that reversing
the lamella order reproduces Eqs. 24-25 exactly.

Discretisation: zero-order hold, ``x⁺ = Φ x + Γ u`` with ``Φ = e^{A dt}`` and
``Γ = ∫₀^dt e^{A s} ds B``, both read from ``expm`` of the augmented matrix
``[[A, B], [0, 0]] · dt`` (balanced first, since the axial mode is extremely stiff: with the
thesis-like damping the fast eigenvalues are ~1e9 1/s). The pack model then uses the
algebraically identical ``Γ = (I − Φ) X_ss`` with the closed-form static gain ``X_ss``
(:func:`static_gain`), which makes the discrete equilibrium equal the series-spring result to
rounding whatever the expm's error (~1e-9 relative on this matrix): every step satisfies
``x⁺ − X_ss u = Φ (x − X_ss u)``. Stable for every dt > 0, since |eig(Φ)| < 1.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = [
    "build_state_space",
    "static_gain",
    "spring_force_matrix",
    "zoh_discretize",
    "pack_discretize",
]


def build_state_space(lamella_count: int, mass: float, stiffness: float,
                      damping: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(A, B)`` of the pack: A is (2N, 2N), B is (2N, N + 1) (module docstring)."""
    n_lam = int(lamella_count)
    km, cm = stiffness / mass, damping / mass
    a = np.zeros((2 * n_lam, 2 * n_lam))
    b = np.zeros((2 * n_lam, n_lam + 1))
    for i in range(n_lam):
        z, v = 2 * i, 2 * i + 1
        a[z, v] = 1.0
        a[v, z] -= km  # spring below lamella i+1 (housing spring for the rear one)
        a[v, v] -= cm
        if i > 0:
            a[v, z - 2] += km
            a[v, v - 2] += cm
        if i < n_lam - 1:  # spring above, towards the front lamella
            a[v, z] -= km
            a[v, v] -= cm
            a[v, z + 2] += km
            a[v, v + 2] += cm
        b[v, 1 + i] = -1.0 / mass
    b[2 * n_lam - 1, 0] = 1.0 / mass
    return a, b


def static_gain(lamella_count: int, stiffness: float) -> np.ndarray:
    """Return X_ss (2N, N + 1) with ``x_eq = X_ss u`` (velocities 0).

    Series springs: ``z_n = n F_act / k − Σ_m min(n, m) F_fm / k``.
    """
    n_lam = int(lamella_count)
    idx = np.arange(1, n_lam + 1)
    gain = np.zeros((2 * n_lam, n_lam + 1))
    gain[0::2, 0] = idx / stiffness
    gain[0::2, 1:] = -np.minimum.outer(idx, idx) / stiffness
    return gain


def spring_force_matrix(lamella_count: int, stiffness: float) -> np.ndarray:
    """Return C (N, 2N) with ``S = C x``: S_n = k (z_n − z_{n−1}), the normal force on n [N]."""
    n_lam = int(lamella_count)
    c = np.zeros((n_lam, 2 * n_lam))
    for i in range(n_lam):
        c[i, 2 * i] = stiffness
        if i > 0:
            c[i, 2 * i - 2] = -stiffness
    return c


def zoh_discretize(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(Φ, Γ)`` of the ZOH discretisation at ``dt`` [s] via the augmented expm.

    Same definition as ``scipy.signal.cont2discrete(..., method="zoh")``; the augmented matrix
    is balanced (diagonal similarity, exact in floating point) before ``expm``.
    """
    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a * dt
    aug[:n, n:] = b * dt
    balanced, (scale, _) = scipy.linalg.matrix_balance(aug, permute=False, separate=True)
    expo = scipy.linalg.expm(balanced)
    expo = expo * scale[:, None] / scale[None, :]
    return expo[:n, :n].copy(), expo[:n, n:].copy()


def pack_discretize(a: np.ndarray, b: np.ndarray, x_ss: np.ndarray,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(Φ, Γ)`` with ``Γ = (I − Φ) X_ss`` (exact equilibrium, module docstring)."""
    phi, _ = zoh_discretize(a, b, dt)
    gamma = (np.eye(phi.shape[0]) - phi) @ x_ss
    return phi, gamma
