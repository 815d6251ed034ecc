"""The layering of ARCHITECTURE.md holds: import contracts, no cycles, a model free of ROS.

- ``lint-imports`` (import-linter, contracts in ``.importlinter``) passes, and the contracts
  name every subpackage of ``clutch_ros``;
- the same contracts fail on a copy of the package with a deliberately wrong import (so the
  check above can fail);
- no import cycle between the package's modules (strongly connected components of grimp's
  import graph, which counts every import statement, function-local ones included);
- the model tests pass in a process where python-can, cantools, rosbags and rclpy cannot be
  imported.
"""

import configparser
import os
import shutil
import subprocess
import sys
from pathlib import Path

import grimp
import pytest

REPO = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")
BLOCKED = ("can", "cantools", "rosbags", "rclpy")


def _lint(cwd: Path, pythonpath: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    return subprocess.run([str(LINT), "--no-cache"], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def _layers() -> list[str]:
    cfg = configparser.ConfigParser()
    cfg.read(REPO / ".importlinter")
    names = []
    for line in cfg["importlinter:contract:layers"]["layers"].split("\n"):
        for part in line.split("|"):
            part = part.strip().strip("()")
            if part:
                names.append(part)
    return names


def test_import_contracts_hold():
    done = _lint(REPO, REPO)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "0 broken" in done.stdout


def test_layers_cover_every_subpackage_and_top_module():
    layers = set(_layers())
    pkg = REPO / "clutch_ros"
    children = {f"clutch_ros.{p.name}" for p in pkg.iterdir()
                if p.is_dir() and (p / "__init__.py").exists()}
    children |= {f"clutch_ros.{p.stem}" for p in pkg.glob("*.py") if p.stem != "__init__"}
    assert children, "found no subpackages: the check would pass vacuously"
    assert children <= layers, f"not in any layer: {sorted(children - layers)}"


def test_contracts_fail_on_a_wrong_import(tmp_path):
    shutil.copytree(REPO / "clutch_ros", tmp_path / "clutch_ros",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / ".importlinter", tmp_path / ".importlinter")
    assert _lint(tmp_path, tmp_path).returncode == 0  # the copy is as clean as the original
    pack = tmp_path / "clutch_ros" / "model" / "pack.py"
    pack.write_text(pack.read_text(encoding="utf-8")
                    + "\nfrom clutch_ros.offline import replay  # noqa: E402,F401\n",
                    encoding="utf-8")
    store = tmp_path / "clutch_ros" / "bag" / "typestore.py"
    store.write_text(store.read_text(encoding="utf-8") + "\nimport rclpy  # noqa: E402,F401\n",
                     encoding="utf-8")
    done = _lint(tmp_path, tmp_path)
    assert done.returncode != 0
    out = done.stdout
    assert "Layers: each layer imports only from the layers below it BROKEN" in out, out[-3000:]
    assert "Only nodes and cli use ROS (rclpy and the generated message packages) BROKEN" in out
    assert "- clutch_ros.model.pack -> clutch_ros.offline.replay" in out
    assert "clutch_ros.bag is not allowed to import rclpy" in out


def _cycles(graph) -> list[list[str]]:
    mods = sorted(m for m in graph.modules if m.startswith("clutch_ros"))
    adj = {m: sorted(x for x in graph.find_modules_directly_imported_by(m)
                     if x.startswith("clutch_ros")) for m in mods}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in adj[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for m in mods:
        if m not in index:
            visit(m)
    return found


def test_no_import_cycles():
    graph = grimp.build_graph("clutch_ros", cache_dir=None)
    assert len(graph.modules) > 50
    assert _cycles(graph) == []


def test_cycle_finder_finds_a_cycle():
    graph = grimp.ImportGraph()
    for a, b in (("clutch_ros.a", "clutch_ros.b"), ("clutch_ros.b", "clutch_ros.c"),
                 ("clutch_ros.c", "clutch_ros.a"), ("clutch_ros.c", "clutch_ros.d")):
        graph.add_import(importer=a, imported=b)
    assert _cycles(graph) == [["clutch_ros.a", "clutch_ros.b", "clutch_ros.c"]]


_BLOCKER = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in {blocked!r}:
            raise ImportError("blocked for this test: " + name)
sys.meta_path.insert(0, Block())
for name in {blocked!r}:
    try:
        __import__(name)
    except ImportError:
        pass
    else:
        raise SystemExit("the import blocker does not work for " + name)
import pytest
sys.exit(pytest.main(["tests/model", "-q", "-x", "-p", "no:cacheprovider"]))
"""


@pytest.mark.slow
def test_model_tests_run_without_ros_can_and_bags():
    code = _BLOCKER.format(blocked=set(BLOCKED))
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                          text=True, timeout=900)
    tail = done.stdout[-3000:] + done.stderr[-2000:]
    assert done.returncode == 0, tail
    assert " passed" in done.stdout and "error" not in done.stdout.splitlines()[-1], tail
