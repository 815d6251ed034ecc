"""Physics of every spline law over Tables 3-4 and the PBD release run (issue 12).

Checked on the simulated pack, law by law:
- friction never does positive work: F_fn Δz_n ≥ 0 on every lamella at every step (the
  package convention: F_fn > 0 opposes compression);
- the axial energy balance closes: actuator work = Δ stored + damping + friction, where the
  damping dissipation of each step is computed independently of the step map, exactly, from
  the Lyapunov solution P of AᵀP + PA = −Q (∫₀^dt eᵀ(s) Q e(s) ds = e₀ᵀPe₀ − e₁ᵀPe₁ for the
  deviation e from the held input's equilibrium, since ė = A e with inputs held);
- under constant pressure (reached from below) no lamella force exceeds the piston force by
  more than 1 %;
- one second after the release the torque is below 1 % of its peak.
The printed Eqs. 29-30 (``ff_t_printed``, ``ff_v_printed``) are shown to break the first
(and ff_t_printed the last two): the reason the passive laws exist.
"""

import numpy as np
import pytest
import scipy.linalg
from numpy.testing import assert_allclose

from clutch_ros.model import simulate
from clutch_ros.model.params import PASSIVE_LAWS
from clutch_ros.model.sequences import pbd_release_sequence, table3, table4
from clutch_ros.model.statespace import build_state_space, static_gain


def _sequences():
    seqs = {f"t3_{s.name}": s for s in table3(10.0)}
    seqs.update({f"t4_pbd_{int(s.slip_rpm)}rpm_{int(s.lamella_temperature[0])}C": s
                 for s in table4()})
    seqs["pbd_release"] = pbd_release_sequence()
    return seqs


SEQUENCES = _sequences()


def _run(params, seq):
    return simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed,
                    seq.lamella_temperature)


def energy_terms(params, seq, res):
    """Return (actuator work, Δ stored, damping, friction work) [J] over the run (held forces)."""
    pk = params.pack
    n, k, c, m = pk.lamella_count, pk.lamella_stiffness, pk.lamella_damping, pk.lamella_mass
    a, _ = build_state_space(n, m, k, c)
    diff = np.eye(n) - np.eye(n, k=-1)  # relative speeds ż_n − ż_{n−1} (ż_0 = 0)
    q = np.zeros((2 * n, 2 * n))
    q[1::2, 1::2] = c * diff.T @ diff
    p_lyap = scipy.linalg.solve_continuous_lyapunov(a.T, -q)
    x = np.empty((len(seq.t), 2 * n))
    x[:, 0::2], x[:, 1::2] = res.positions, res.velocities
    f_act = np.maximum(seq.actuating_pressure, 0.0) * pk.piston_area
    u = np.column_stack([f_act[1:], res.spline_force[1:]])  # inputs held over step k
    x_ss = u @ static_gain(n, k).T
    e0, e1 = x[:-1] - x_ss, x[1:] - x_ss
    damping = (np.einsum("ij,jk,ik->i", e0, p_lyap, e0)
               - np.einsum("ij,jk,ik->i", e1, p_lyap, e1)).sum()
    dz = np.diff(res.positions, axis=0)
    actuator = (f_act[1:] * dz[:, -1]).sum()
    friction = (res.spline_force[1:] * dz).sum()
    stretch = np.diff(np.column_stack([np.zeros(len(seq.t)), res.positions]), axis=1)
    stored = 0.5 * m * (res.velocities ** 2).sum(axis=1) + 0.5 * k * (stretch ** 2).sum(axis=1)
    return actuator, stored[-1] - stored[0], damping, friction


@pytest.mark.parametrize("name", list(SEQUENCES))
@pytest.mark.parametrize("law", PASSIVE_LAWS)
def test_passive_laws_physics(flexiforce, law, name):
    params = flexiforce.with_law(law)
    seq = SEQUENCES[name]
    res = _run(params, seq)
    # 1. friction never does positive work, per lamella and step, beyond round-off: a stuck
    #    lamella's displacement is zero to the solver's tolerance, 1e-12 of the largest move
    #    in the step (~1e-5 m), i.e. ~1e-17 m against ~2e2 N: a few 1e-15 J
    dz = np.diff(res.positions, axis=0)
    work = res.spline_force[1:] * dz
    tol = 1e-10 * np.abs(res.spline_force).max() * np.abs(dz).max()
    assert work.min() >= -tol
    # 2. energy balance, damping from the Lyapunov integral (independent of the step map)
    actuator, stored, damping, friction = energy_terms(params, seq, res)
    assert actuator > 0.0 and damping > 0.0 and friction >= -1e-15  # J, round-off
    assert_allclose(actuator, stored + damping + friction, rtol=1e-3)
    # 3. constant pressure reached from below (at the highest level so far): no lamella force
    #    above the piston force by more than 1 %. (After a decrease the pack rightly carries
    #    more than the piston force while it relaxes, and coulomb keeps it: Hypothesis 1(c).)
    f_act = seq.actuating_pressure * params.pack.piston_area
    const = np.zeros(len(seq.t), dtype=bool)
    highest = np.maximum.accumulate(seq.actuating_pressure)
    const[1:] = ((np.diff(seq.actuating_pressure) == 0.0) & (f_act[1:] > 0.0)
                 & (seq.actuating_pressure[1:] >= highest[1:]))
    assert (res.normal_force[const].max(axis=1) <= 1.01 * f_act[const]).all()
    # 4. one second after the release, below 1 % of the peak torque
    release = seq.active[1]
    later = seq.t >= release + 1.0
    peak = np.abs(res.torque).max()
    assert peak > 100.0  # N m: the run did transmit torque
    assert np.abs(res.torque[later]).max() < 0.01 * peak


def test_printed_laws_are_not_passive(flexiforce):
    seq = SEQUENCES["pbd_release"]
    for law in ("ff_t_printed", "ff_v_printed"):
        res = _run(flexiforce.with_law(law), seq)
        work = res.spline_force[1:] * np.diff(res.positions, axis=0)
        assert work.min() < -1e-6, law  # J: friction pushes a lamella along its motion
    res = _run(flexiforce.with_law("ff_t_printed"), seq)
    f_act = seq.actuating_pressure * flexiforce.pack.piston_area
    hold = (seq.t > seq.active[0] + 0.5) & (seq.t < seq.active[1])
    assert (res.normal_force[hold].max(axis=1) / f_act[hold]).max() > 1.1
    later = seq.t >= seq.active[1] + 1.0
    assert np.abs(res.torque[later]).max() > 0.03 * np.abs(res.torque).max()


def test_energy_balance_of_held_printed_law_still_closes(flexiforce):
    """The balance itself is law-independent: ff_v_printed holds its force, so it closes too.

    (Some of its friction work is negative: energy put into the pack by the law.)
    """
    params = flexiforce.with_law("ff_v_printed")
    seq = SEQUENCES["t3_inc_step"]
    res = _run(params, seq)
    actuator, stored, damping, friction = energy_terms(params, seq, res)
    assert_allclose(actuator, stored + damping + friction, rtol=1e-3)
