"""The compiled model loop (numba) equals the numpy reference path on the golden sequences.

Every law the kernel knows runs every test sequence of the thesis (Tables 3-4, 10 and 30 rpm,
:mod:`clutch_ros.model.sequences`) and the PBD run released while slipping through
:func:`simulate` twice: ``engine="kernel"`` and ``engine="numpy"`` (the per-sample
``PackModel._advance`` loop), with a measured
temperature ramp and without one (NaN: the thermal state), on the estimator preset and on the
rig truth preset (oil film on). Tolerances: rtol 1e-9 on torque, pressures, μ, temperature and
film (both paths do the same float operations; the matrix-vector products are summed in a
different order, observed ≤ 1e-10); spline forces within 1e-6 of the run's largest spline
force for the laws that solve a box problem per step (coulomb, passive ff_t / ff_v: the
active-set solution is unique, its acceptance tolerances are 1e-12 relative, and the stuck
subsystem's conditioning amplifies that; observed ≤ 2e-7). The model must end in the same
state, so a step loop can continue either way. Without numba the numpy path runs and says
why in the log.
"""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from clutch_ros.config.params_file import load_params
from clutch_ros.config.presets import preset_path
from clutch_ros.model import PackModel, kernel, make_sequence, simulate
from clutch_ros.model.batch import estimate_batch
from clutch_ros.model.errors import InputError
from clutch_ros.model.sequences import SEQUENCE_NAMES

LAWS = sorted(kernel.LAW_CODES)
BOX_LAWS = {"coulomb", "ff_t", "ff_v"}
SEQUENCES = [(name, rpm) for name in (*SEQUENCE_NAMES, "pbd_release") for rpm in (10.0, 30.0)]


def _both(params, seq, temperature):
    args = (params, seq.t, seq.actuating_pressure, seq.slip_speed, temperature)
    m_kernel, m_numpy = PackModel(params), PackModel(params)
    fast = simulate(*args, model=m_kernel, engine="kernel")
    ref = simulate(*args, model=m_numpy, engine="numpy")
    assert (fast.engine, ref.engine) == ("kernel", "numpy")
    return fast, ref, m_kernel, m_numpy


def test_kernel_is_available():
    """Numba is pinned: the suite must exercise the compiled path, not skip it."""
    assert kernel.available(), kernel.unavailable_reason()


@pytest.mark.parametrize("preset", ["flexiforce_8", "rig_truth"])
@pytest.mark.parametrize("law", LAWS)
def test_compiled_equals_numpy_on_the_golden_sequences(preset, law):
    params = load_params(preset_path(preset)).with_law(law)
    for name, rpm in SEQUENCES:
        seq = make_sequence(name, rpm)
        temperatures = [np.full(seq.t.size, math.nan)]  # thermal state (and film on the rig)
        if preset == "flexiforce_8":
            temperatures.append(np.linspace(35.0, 90.0, seq.t.size))  # measured
        for temperature in temperatures:
            fast, ref, m_fast, m_ref = _both(params, seq, temperature)
            where = f"{preset} {law} {name} {rpm:g} rpm"
            for field in ("torque", "reference_torque", "front_pressure", "rear_pressure",
                          "mu", "lamella_temperature", "film", "compression"):
                a, b = getattr(fast, field), getattr(ref, field)
                scale = float(np.abs(b).max())
                np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * scale,
                                           err_msg=f"{where}: {field}")
            fmax = float(np.abs(ref.spline_force).max())
            tol = 1e-6 if law in BOX_LAWS else 1e-9
            np.testing.assert_allclose(fast.spline_force, ref.spline_force, rtol=0,
                                       atol=tol * fmax + 1e-12, err_msg=f"{where}: forces")
            np.testing.assert_allclose(m_fast._work, m_ref._work, rtol=1e-9,
                                       atol=1e-9 * float(np.abs(m_ref._work).max()))
            assert (m_fast._film, m_fast._temp) == pytest.approx((m_ref._film, m_ref._temp),
                                                                 rel=1e-9)


def test_a_changed_sample_changes_the_compiled_result():
    """The comparison above can fail: one perturbed pressure sample changes the torque."""
    params = load_params(preset_path("flexiforce_8"))
    seq = make_sequence(SEQUENCE_NAMES[0], 10.0)
    p = seq.actuating_pressure.copy()
    a = simulate(params, seq.t, p, seq.slip_speed, 60.0)
    p[p.size // 2] += 1e5
    b = simulate(params, seq.t, p, seq.slip_speed, 60.0)
    assert np.abs(a.torque - b.torque).max() > 1e-3


def test_estimate_batch_uses_the_kernel_and_equals_numpy():
    """The batch estimator (replay, golden) passes the engine through; same tolerances."""
    params = load_params(preset_path("flexiforce_8")).with_law("coulomb")
    seq = make_sequence("pbd_release", 10.0)
    args = (params, seq.t, seq.actuating_pressure, seq.lamella_temperature, seq.slip_speed)
    fast = estimate_batch(*args, engine="kernel")
    ref = estimate_batch(*args, engine="numpy")
    scale = float(np.abs(ref.modelled_torque).max())
    # rtol 1e-9 as above; atol 1e-12 of the run's largest torque for the zero samples
    np.testing.assert_allclose(fast.modelled_torque, ref.modelled_torque, rtol=1e-9,
                               atol=1e-12 * scale)


@pytest.mark.parametrize("law", LAWS)
def test_estimate_batch_columns_path_equals_numpy_in_every_field(law):
    """The output-only loop (simulate_columns, what replay and fit run) against numpy.

    Every EstimateBatch field, with a measured temperature and without (thermal state), with
    rejected samples and a gap (two segments, non-contiguous rows). Tolerances as above:
    rtol 1e-9 (atol 1e-12 of the field's largest value) on every field except P_diff and the
    spline forces; P_diff = front − rear is a difference of two nearly equal pressures, so
    its rounding is relative to the pressures: atol 1e-12 of the largest front pressure;
    spline forces (and spline_correction, a weighted sum of them) within 1e-6 of the
    largest force for the box laws, 1e-9 otherwise.
    """
    params = load_params(preset_path("flexiforce_8")).with_law(law)
    seq = make_sequence("pbd_release", 30.0)
    t = seq.t.copy()
    t[t.size // 2:] += 2.0  # a gap longer than max_gap_s: a second segment
    p = seq.actuating_pressure.copy()
    p[7] = math.nan  # rejected: non-finite
    t[11] = t[10]  # rejected: duplicate stamp
    measured = np.where(np.arange(t.size) % 5 == 0, math.nan, 50.0)
    for temp in (np.linspace(35.0, 90.0, t.size), np.full(t.size, math.nan)):
        args = (params, t, p, temp, seq.slip_speed, measured)
        fast = estimate_batch(*args, on_reject="skip", engine="kernel")
        ref = estimate_batch(*args, on_reject="skip", engine="numpy")
        lean = estimate_batch(*args, on_reject="skip", engine="kernel", per_lamella=False)
        assert lean.lamella_normal_force is None and lean.spline_friction_force is None
        force_tol = 1e-6 if law in BOX_LAWS else 1e-9
        fmax = float(np.nanmax(np.abs(ref.spline_friction_force))) + 1e-12
        front = float(np.nanmax(np.abs(ref.front_pressure)))
        for field in ("accepted", "reinitialised", "overshoot", "undershoot"):
            assert np.array_equal(getattr(fast, field), getattr(ref, field)), field
        for field in ("stamp", "modelled_torque", "reference_torque", "measured_torque",
                      "torque_accuracy", "friction_coefficient", "lamella_normal_force",
                      "spline_friction_force", "front_pressure", "rear_pressure",
                      "pressure_difference", "slip_speed_filtered", "actuating_pressure",
                      "lamella_temperature", "slip_speed", "compression",
                      "spline_correction"):
            a, b = getattr(fast, field), getattr(ref, field)
            scale = float(np.nanmax(np.abs(b))) if np.isfinite(b).any() else 0.0
            rtol, atol = 1e-9, 1e-12 * scale
            if field == "pressure_difference":
                atol = 1e-12 * front
            elif field == "spline_friction_force":
                rtol, atol = 0.0, force_tol * fmax
            elif field == "spline_correction":
                rtol = 0.0
                n_lam, area = params.pack.lamella_count, params.pack.piston_area
                atol = force_tol * fmax * (n_lam + 1) / (2 * area)  # Σ n F_n / (N A)
            np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, err_msg=f"{law}: {field}")
            if field not in ("lamella_normal_force", "spline_friction_force"):
                np.testing.assert_array_equal(getattr(lean, field), a, err_msg=field)
        assert not fast.accepted[7] and not fast.accepted[11] and fast.reinitialised.sum() == 2


def test_compiled_slip_lowpass_equals_numpy():
    """The estimator's slip filter over a jittery series: same operations, so rtol 1e-13."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(5e-4, 1.5e-3, 5000))
    u = np.sign(np.sin(t * 3.0)) * 3.0 + rng.normal(0.0, 0.1, t.size)
    fast = kernel.lowpass_series(t, u, 0.02, "kernel")
    ref = kernel.lowpass_series(t, u, 0.02, "numpy")
    np.testing.assert_allclose(fast, ref, rtol=1e-13, atol=1e-15)
    assert np.abs(ref - u).max() > 0.5  # the filter really filters: the check can fail


def test_numba_is_imported_lazily():
    """Importing the model (every CLI start-up) does not load numba; the first simulate does."""
    code = ("import sys\n"
            "import clutch_ros.model.simulate, clutch_ros.model.estimator\n"
            "print('numba' in sys.modules)\n"
            "from clutch_ros.model import kernel\n"
            "kernel.available()\n"
            "print('numba' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "True"]


def test_an_unknown_engine_is_refused():
    seq = make_sequence("step", 10.0)
    with pytest.raises(InputError, match="engine must be one of"):
        simulate(load_params(preset_path("flexiforce_8")), seq.t, seq.actuating_pressure,
                 seq.slip_speed, 60.0, engine="cuda")


def test_without_numba_the_numpy_path_runs_and_says_why():
    code = (
        "import importlib.abc, logging, sys\n"
        "class Block(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path, target=None):\n"
        "        if name.split('.')[0] == 'numba':\n"
        "            raise ImportError('blocked for this test')\n"
        "sys.meta_path.insert(0, Block())\n"
        "logging.basicConfig(level=logging.INFO)\n"
        "from clutch_ros.config.params_file import load_params\n"
        "from clutch_ros.config.presets import preset_path\n"
        "from clutch_ros.model import kernel, make_sequence, simulate\n"
        "seq = make_sequence('step', 10.0)\n"
        "r = simulate(load_params(preset_path('flexiforce_8')), seq.t, seq.actuating_pressure,"
        " seq.slip_speed, 60.0)\n"
        "print(kernel.available(), r.engine, float(r.torque[-1]))\n"
        "try:\n"
        "    simulate(load_params(preset_path('flexiforce_8')), seq.t, seq.actuating_pressure,"
        " seq.slip_speed, 60.0, engine='kernel')\n"
        "except kernel.KernelUnavailableError as err:\n"
        "    print('refused:', err)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    first, refused = done.stdout.splitlines()
    available, engine, torque = first.split()
    assert available == "False" and engine == "numpy" and math.isfinite(float(torque))
    # engine="kernel" does not fall back: it says why it cannot run
    assert refused.startswith("refused: engine='kernel': numba cannot be imported")
    assert "numba cannot be imported" in done.stderr and "numpy path" in done.stderr


def test_a_failed_compilation_falls_back_to_numpy_and_says_why(tmp_path):
    """A kernel that numba cannot type: auto runs numpy (logged), kernel refuses."""
    (tmp_path / "broken.py").write_text(
        "def film_step(fr, film, dt, pressure, slip_speed):\n"
        "    return 'not a number' + film\n")
    code = (
        "import logging, sys\n"
        f"sys.path.insert(0, {str(tmp_path)!r})\n"
        "logging.basicConfig(level=logging.INFO)\n"
        "import broken\n"
        "from clutch_ros.config.params_file import load_params\n"
        "from clutch_ros.config.presets import preset_path\n"
        "from clutch_ros.model import kernel, kernel_loop, make_sequence, simulate\n"
        "kernel_loop._film_step = broken.film_step\n"
        "seq = make_sequence('step', 10.0)\n"
        "params = load_params(preset_path('rig_truth'))\n"
        "r = simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed, 60.0)\n"
        "ref = simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed, 60.0,"
        " engine='numpy')\n"
        "print(kernel.available(), r.engine, bool((r.torque == ref.torque).all()))\n"
        "try:\n"
        "    simulate(params, seq.t, seq.actuating_pressure, seq.slip_speed, 60.0,"
        " engine='kernel')\n"
        "except kernel.KernelUnavailableError as err:\n"
        "    print('refused:', err)\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    first, refused = done.stdout.splitlines()
    assert first == "False numpy True"
    assert refused.startswith("refused: engine='kernel': compilation failed (TypingError")
    assert "compilation failed" in done.stderr and "numpy path" in done.stderr
