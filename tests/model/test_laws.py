"""The spline-law registry (model/laws.py): one table every other module reads (issue 25).

Consistency of the registered laws with the names the rest of the package imports, every law
constructs and the passive ones do no positive work, and adding a law is one registry entry
plus the law's class: params validation, make_spline_law, identification and the numpy
simulation accept it with no other edit; the compiled kernel refuses it with a clear error.
"""

import ast
import pickle
from pathlib import Path

import numpy as np
import pytest

from clutch_ros.model import errors, kernel, kernel_box, laws
from clutch_ros.model.adaptation import GAIN_LAWS
from clutch_ros.model.fit_data import SAMPLE_BUDGET
from clutch_ros.model.fit_problem import TRANSFORM
from clutch_ros.model.identification import FREE_PARAMETERS, initial_params
from clutch_ros.model.params import PARAMETER_SPECS, PASSIVE_LAWS, SPLINE_LAWS, TABLE7
from clutch_ros.model.simulate import simulate
from clutch_ros.model.spline import SplineLaw

MODEL_DIR = Path(laws.__file__).resolve().parent
KERNEL_KINDS = (kernel_box.NONE, kernel_box.LINEAR, kernel_box.VISCOUS, kernel_box.BOX)
BOX_VARIANTS = (kernel_box.COULOMB, kernel_box.FF_T, kernel_box.FF_V)


def test_public_names_are_the_registry():
    names = laws.law_names()
    assert names == ("none", "ff_t", "ff_v", "coulomb", "ff_t_printed", "ff_v_printed")
    assert tuple(SPLINE_LAWS) == names and SPLINE_LAWS == names
    assert tuple(PASSIVE_LAWS) == tuple(n for n in names if laws.law_info(n).passive)
    assert tuple(PASSIVE_LAWS) == ("none", "ff_t", "ff_v", "coulomb")
    assert not any(laws.law_info(n).passive for n in names if n.endswith("_printed"))
    assert tuple(GAIN_LAWS) == ("ff_t", "ff_v")
    assert tuple(PARAMETER_SPECS["spline.law"].choices) == names
    assert tuple(FREE_PARAMETERS) == names and tuple(SAMPLE_BUDGET) == names
    assert tuple(kernel.LAW_CODES) == names


def test_the_live_views_pickle_and_stay_live():
    for view in (SPLINE_LAWS, PASSIVE_LAWS, GAIN_LAWS, FREE_PARAMETERS, SAMPLE_BUDGET,
                 kernel.LAW_CODES):
        copy = pickle.loads(pickle.dumps(view))  # process pools, dask
        assert copy == view and type(copy) is type(view)
    assert PASSIVE_LAWS[1:3] == ("ff_t", "ff_v") and len(GAIN_LAWS) == 2
    assert "ff_t" in GAIN_LAWS and "ff_t_printed" not in GAIN_LAWS and 3 not in SPLINE_LAWS
    assert dict(SAMPLE_BUDGET)["coulomb"] == SAMPLE_BUDGET["coulomb"] == 4_000
    with pytest.raises(KeyError):
        FREE_PARAMETERS["no_such_law"]


def test_registry_entries_are_consistent(flexiforce):
    for name in laws.law_names():
        info = laws.law_info(name)
        law = laws.make_spline_law(flexiforce.with_law(name))
        assert type(law) is info.load() and issubclass(info.load(), SplineLaw)
        assert law.name == name  # the class's own name matches its entry
        assert info.kernel is not None
        kind, variant = info.kernel
        assert kind in KERNEL_KINDS and (kind != kernel_box.BOX or variant in BOX_VARIANTS)
        assert info.free_parameters and set(info.free_parameters) <= set(TRANSFORM)
        assert set(info.free_parameters) <= set(PARAMETER_SPECS)
        assert {k for k, _ in info.start} <= set(info.free_parameters)
        assert info.sample_budget > 0
        assert info.has_gain == (info.gain_unit is not None)
        assert not info.adapts_gain or info.has_gain
        if info.table7 is not None:
            assert (info.table7, 10) in TABLE7 and info.has_gain
            assert {"spline.gain", "spline.time_constant"} <= set(info.free_parameters)
    # the box laws share one kernel kind, each with its own variant
    box = [laws.law_info(n).kernel[1] for n in laws.law_names()
           if laws.law_info(n).kernel[0] == kernel_box.BOX]
    assert sorted(box) == sorted(BOX_VARIANTS)


@pytest.mark.parametrize("name", laws.law_names("passive"))
def test_passive_laws_do_no_positive_work_on_a_random_sequence(flexiforce, name):
    rng = np.random.default_rng(25)
    n = 3000
    t = np.arange(n) * 1e-3
    # random pressure steps and ramps (up and down), slip that reverses, temperature drift
    levels = rng.uniform(0.0, 40e5, size=30)
    p = np.interp(t, np.linspace(0.0, t[-1], levels.size), levels)
    p[rng.integers(0, n, size=40)] += rng.uniform(-5e5, 5e5, size=40)
    p = np.maximum(p, 0.0)
    w = 1.0 * np.sin(2 * np.pi * t / 1.3)
    temp = 35.0 + 5.0 * t
    res = simulate(flexiforce.with_law(name), t, p, w, temp, engine="numpy")
    dz = np.diff(res.positions, axis=0)
    work = res.spline_force[1:] * dz  # F_fn > 0 opposes compression
    scale = max(np.abs(res.spline_force).max() * np.abs(dz).max(), 1e-300)
    assert work.min() >= -1e-10 * scale


def test_unknown_law_is_a_parameter_error_naming_the_key(flexiforce):
    with pytest.raises(errors.ParameterError, match="spline.law"):
        flexiforce.with_law("no_such_law")
    with pytest.raises(errors.UnknownLawError, match="no_such_law") as info:
        laws.law_info("no_such_law")
    assert isinstance(info.value, errors.ModelError) and info.value.key == "spline.law"
    assert "ff_t" in str(info.value)  # lists the registered laws
    with pytest.raises(ValueError, match="registered already"):
        laws.register(laws.law_info("ff_t"))


class _DummyLaw(SplineLaw):
    """A law with no force and no state under another name (what a new law starts from)."""

    name = "dummy"


@pytest.fixture
def dummy(monkeypatch):
    """Register ``dummy`` for one test: the one entry a new law needs (no kernel code)."""
    info = laws.SplineLawInfo("dummy", _DummyLaw, passive=True, sample_budget=1234,
                              free_parameters=laws.FRICTION_PARAMETERS)
    monkeypatch.setitem(laws._REGISTRY, "dummy", info)
    return info


def test_a_new_law_is_one_registry_entry(flexiforce, dummy):
    # parameters: the spline.law choices, the public name lists
    params = flexiforce.with_law("dummy")
    assert params.spline.law == "dummy" and params.spline.gain == flexiforce.spline.gain
    assert PARAMETER_SPECS["spline.law"].check("dummy") == "dummy"
    assert "dummy" in SPLINE_LAWS and "dummy" in PASSIVE_LAWS and "dummy" not in GAIN_LAWS
    # the pack builds it
    assert type(laws.make_spline_law(params)) is _DummyLaw
    # identification: its free parameters, start values and budget
    assert FREE_PARAMETERS["dummy"] == laws.FRICTION_PARAMETERS
    assert SAMPLE_BUDGET["dummy"] == 1234
    assert initial_params(flexiforce, "dummy").spline.law == "dummy"
    # the numpy path runs it (no force: the Eq. 1 pack, like "none")
    t = np.arange(200) * 1e-3
    res = simulate(params, t, np.full(t.size, 20e5), 1.0, 35.0, engine="numpy")
    ref = simulate(flexiforce.with_law("none"), t, np.full(t.size, 20e5), 1.0, 35.0,
                   engine="numpy")
    np.testing.assert_array_equal(res.torque, ref.torque)
    assert res.law == "dummy"
    # the compiled loop has no code for it: auto falls back to numpy, kernel says why
    assert "dummy" not in kernel.LAW_CODES
    auto = simulate(params, t, np.full(t.size, 20e5), 1.0, 35.0, engine="auto")
    assert auto.engine == "numpy"
    np.testing.assert_array_equal(auto.torque, res.torque)
    if kernel.available():
        with pytest.raises(errors.KernelUnavailableError, match="no compiled code.*'dummy'"):
            simulate(params, t, np.full(t.size, 20e5), 1.0, 35.0, engine="kernel")
    # gone with the entry
    del laws._REGISTRY["dummy"]
    assert "dummy" not in SPLINE_LAWS and "dummy" not in FREE_PARAMETERS


def _string_constants(tree):
    """Yield the string constants of a module that are not docstrings."""
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docs.add(id(first.value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docs:
            yield node


def _allowed(tree):
    """Ids of the nodes that may spell a law name outside laws.py.

    A law class's own ``name = "..."`` (its module names it), and the thesis's Table 7 data
    (``TABLE7``: its columns are labelled by law; the registry's ``table7`` points at them).
    """
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for stmt in node.body:
                if isinstance(stmt, ast.Assign) and \
                        [getattr(t, "id", None) for t in stmt.targets] == ["name"]:
                    own.add(id(stmt.value))
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == "TABLE7":
            own.update(id(sub) for sub in ast.walk(node.value))
    return own


def test_no_module_but_the_registry_spells_a_law_name():
    """Law names appear as code only in laws.py (docstrings and comments aside)."""
    names = set(laws.law_names())
    found = []
    for path in sorted(MODEL_DIR.glob("*.py")):
        if path.name == "laws.py":
            continue
        tree = ast.parse(path.read_text())
        own = _allowed(tree)
        found += [f"{path.name}:{node.lineno} {node.value!r}" for node in _string_constants(tree)
                  if node.value in names and id(node) not in own]
    assert not found, found
