"""Style is enforced as a test: ruff (pycodestyle, pyflakes, isort, pydocstyle, bugbear...)."""

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO


def test_ruff_clean():
    ruff = Path(sys.executable).with_name("ruff")
    done = subprocess.run([str(ruff), "check", "--no-cache", "clutch_ros", "tests", "benchmarks",
                           "tools"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-5000:] + done.stderr[-2000:]


def test_no_print_outside_cli():
    # ruff's T20 rule does this too; this keeps the rule from being silently dropped.
    offenders = []
    for path in (REPO / "clutch_ros").rglob("*.py"):
        if "cli" in path.parts or path.name == "bench.py":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if line.lstrip().startswith("print("):
                offenders.append(f"{path.relative_to(REPO)}:{number}")
    assert not offenders, offenders
