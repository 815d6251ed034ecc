"""package.xml declares a rosdep key for every third-party module clutch_ros imports.

The imports come from an ast scan of every module under ``clutch_ros/`` (function-local
imports of optional packages included); each top-level module is mapped to its rosdep key
by :data:`ROSDEP_KEYS` (the keys exist in the rosdistro database: ``rosdep/python.yaml``,
``rosdep/base.yaml`` or a ROS package name). A module without a rosdep key must be listed in
:data:`PIP_ONLY` with the README's pip instruction. Both directions are checked: no import
without a key, no declared key without an import.
"""

import ast
import sys
import xml.etree.ElementTree as ET

from tests.conftest import REPO

#: top-level module -> rosdep key
ROSDEP_KEYS = {
    "rclpy": "rclpy",
    "rcl_interfaces": "rcl_interfaces",
    "builtin_interfaces": "builtin_interfaces",
    "diagnostic_msgs": "diagnostic_msgs",
    "rosgraph_msgs": "rosgraph_msgs",
    "lifecycle_msgs": "lifecycle_msgs",
    "std_msgs": "std_msgs",
    "ament_index_python": "ament_index_python",
    "clutch_msgs": "clutch_msgs",
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "can": "python3-can",
    "cantools": "python3-cantools-pip",
    "rosbags": "python3-rosbags-pip",
    "ruamel": "python3-ruamel.yaml",
    "pytest": "python3-pytest",
    "hypothesis": "python3-hypothesis",
}
#: modules with no rosdep key: installed with pip as README.md says
PIP_ONLY = {"asammdf": "asammdf==8.8.28", "foxglove": "foxglove-sdk==0.30.3",
            "distributed": "distributed==2026.8.0", "numba": "numba==0.68.1"}
#: modules the package imports only as what a declared package installs: module -> why
PROVIDED = {
    "lz4": "python3-rosbags-pip (a rosbags dependency; lz4-compressed MCAP chunks)",
    "backports": "python3-rosbags-pip (backports.zstd, a rosbags dependency before 3.14)",
    "compression": "the standard library's compression.zstd from Python 3.14",
}
#: test-only keys (imported by tests/, not by the package)
TEST_KEYS = {"python3-pytest", "python3-hypothesis"}


def _imports(root) -> set[str]:
    found = set()
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split(".")[0])
    return {m for m in found if m not in sys.stdlib_module_names and m != "clutch_ros"}


def _declared() -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for elem in ET.parse(REPO / "package.xml").getroot():
        if elem.tag.endswith("depend"):
            out.setdefault(elem.text.strip(), set()).add(elem.tag)
    return out


def test_every_import_has_a_declared_rosdep_key():
    declared = _declared()
    imports = _imports(REPO / "clutch_ros")
    unmapped = sorted(imports - set(ROSDEP_KEYS) - set(PIP_ONLY) - set(PROVIDED))
    assert not unmapped, f"add these modules to ROSDEP_KEYS and package.xml: {unmapped}"
    missing = sorted(ROSDEP_KEYS[m] for m in imports if m in ROSDEP_KEYS
                     and not declared.get(ROSDEP_KEYS[m], set()) & {"depend", "exec_depend"})
    assert not missing, f"package.xml lacks <exec_depend> for {missing}"


def test_no_declared_key_without_an_import():
    runtime = {ROSDEP_KEYS[m] for m in _imports(REPO / "clutch_ros") if m in ROSDEP_KEYS}
    stale = sorted(k for k, tags in _declared().items()
                   if tags & {"depend", "exec_depend"} and k not in runtime)
    assert not stale, f"package.xml declares keys nothing imports: {stale}"


def test_test_imports_have_test_keys():
    declared = _declared()
    test_only = _imports(REPO / "tests") - _imports(REPO / "clutch_ros")
    for module in sorted(test_only):
        key = ROSDEP_KEYS.get(module)
        if key in TEST_KEYS:
            assert "test_depend" in declared.get(key, set()), key


def test_pip_only_modules_are_in_the_readme_and_requirements():
    readme = (REPO / "README.md").read_text()
    requirements = (REPO / "requirements.txt").read_text().split()
    for module, pin in PIP_ONLY.items():
        assert pin in requirements, (module, pin)
        assert f"pip install {pin}" in readme or pin in readme, module
