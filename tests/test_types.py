"""Types are enforced as a test: mypy over the whole package with the repository's mypy.ini.

The package is checked at mypy's default level with ``check_untyped_defs``; ``model/``,
``canbus/`` and ``rigstate.py`` with the full ``--strict`` flag set (sections of mypy.ini). A
control proves that the check can fail: planted modules in a strict and in a default section,
checked with the same configuration.
"""

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

MYPY = Path(sys.executable).with_name("mypy")
CONFIG = REPO / "mypy.ini"


def _mypy(cwd: Path, cache: Path, *files: str) -> subprocess.CompletedProcess:
    # --cache-dir: nothing is written into the repository; the files come from mypy.ini when
    # none are given.
    return subprocess.run([str(MYPY), "--config-file", str(CONFIG), "--cache-dir", str(cache),
                           "--no-error-summary", "--hide-error-context", *files], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_mypy_clean(tmp_path):
    done = _mypy(REPO, tmp_path / "cache")
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-2000:]


_UNTYPED = "def scale(x, k=2.0):\n    return x * k\n"
_WRONG = "def half(x: float) -> int:\n    return x / 2\n"


def test_mypy_fails_on_planted_errors(tmp_path):
    root = tmp_path / "src"
    for sub in ("model", "canbus", "offline"):
        (root / "clutch_ros" / sub).mkdir(parents=True)
        (root / "clutch_ros" / sub / "__init__.py").write_text("")
    (root / "clutch_ros" / "__init__.py").write_text("")
    files = {
        "clutch_ros/model/planted.py": _UNTYPED,       # strict section: untyped def
        "clutch_ros/canbus/planted.py": _WRONG,        # strict section: wrong return type
        "clutch_ros/offline/untyped.py": _UNTYPED,     # default section: allowed
        "clutch_ros/offline/wrong.py": _WRONG,         # default section: still a type error
    }
    for name, text in files.items():
        (root / name).write_text(text)
    done = _mypy(root, tmp_path / "cache", *files)
    out = done.stdout
    assert done.returncode == 1, out + done.stderr
    assert "clutch_ros/model/planted.py:1: error: Function is missing a type annotation" in out
    assert "clutch_ros/canbus/planted.py:2: error: Incompatible return value type" in out
    assert "clutch_ros/offline/wrong.py:2: error: Incompatible return value type" in out
    assert "offline/untyped.py" not in out, out
