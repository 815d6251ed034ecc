"""model/ may import only the standard library, numpy, scipy and clutch_ros.errors/.model.

Exception: the compiled loops import numba, lazily and only once the kernel is available:
model/kernel.py (tests/model/test_kernel.py) and model/compliance.py
(tests/model/test_compliance.py).
"""

import ast
import sys
from pathlib import Path

import clutch_ros.model

MODEL_DIR = Path(clutch_ros.model.__file__).parent
ALLOWED_ROOTS = {"numpy", "scipy"}
ALLOWED_PACKAGE = ("clutch_ros.errors", "clutch_ros.model")
#: module -> further roots it may import (the compiled kernel: numba)
ALLOWED_IN = {"kernel.py": {"numba"}, "compliance.py": {"numba"}}


def _imports(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import stays inside clutch_ros.model
                yield node.lineno, "clutch_ros.model"
            else:
                yield node.lineno, node.module or ""


def _allowed(name: str, module: str = "") -> bool:
    root = name.split(".")[0]
    if root in sys.stdlib_module_names or root in ALLOWED_ROOTS | ALLOWED_IN.get(module, set()):
        return True
    return any(name == p or name.startswith(p + ".") for p in ALLOWED_PACKAGE)


def test_every_model_module_imports_only_numpy_scipy_stdlib():
    modules = sorted(MODEL_DIR.glob("*.py"))
    assert len(modules) >= 12  # the checker really looks at the package
    bad = [f"{path.name}:{line}: {name}" for path in modules for line, name in _imports(path)
           if not _allowed(name, path.name)]
    assert not bad, "forbidden imports in clutch_ros/model: " + ", ".join(bad)


def test_checker_rejects_forbidden_names():
    # the rule itself: these must be refused, else the test above could never fail
    for name in ("rclpy", "can", "rosbags.highlevel", "yaml", "clutch_ros.nodes.estimator",
                 "clutch_ros.config.params_file", "clutch_ros"):
        assert not _allowed(name), name
    assert not _allowed("numba", "pack.py") and _allowed("numba", "kernel.py")
    for name in ("math", "numpy.linalg", "scipy.signal", "clutch_ros.model.pack",
                 "clutch_ros.errors"):
        assert _allowed(name), name
