"""package.xml declares a rosdep key for every third-party module clutch_ros imports.

The imports come from an ast scan of every module under ``clutch_ros/`` (function-local
imports of optional packages included); each top-level module is mapped to its rosdep key
by :data:`ROSDEP_KEYS` (the keys exist in the rosdistro database: ``rosdep/python.yaml``,
``rosdep/base.yaml`` or a ROS package name). A module without a rosdep key must be listed in
:data:`PIP_ONLY` with its pins, and the README's rig-PC section must install exactly those
pins with ``pip install`` lines (plus the tested versions of the pip keys, :data:`PIP_KEYS`),
at the versions ``requirements.txt`` pins. Both directions are checked: no import without a
key or pip line, no declared key or pip line without an import. The README's rosdep and
colcon commands name every package of the repository (rosdep and colcon look no deeper than
a folder holding a package.xml, and ``msg_defs/`` is one inside ``clutch_ros``).
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
#: modules with no rosdep key -> the pins the README's pip lines install
PIP_ONLY = {
    "lz4": ("lz4==4.4.5",),
    "backports": ("backports.zstd==1.8.0",),
    "asammdf": ("asammdf==8.8.28",),
    "foxglove": ("foxglove-sdk==0.30.3",),
    "distributed": ("dask==2026.8.0", "distributed==2026.8.0"),
    "numba": ("numba==0.68.1",),
}
#: rosdep keys that rosdep installs with pip (newest version) -> their pip package, which the
#: README pins at the tested version
PIP_KEYS = {"python3-cantools-pip": "cantools", "python3-rosbags-pip": "rosbags"}
#: modules the package imports only where the interpreter has them: module -> why
PROVIDED = {
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


def _requirements() -> dict[str, str]:
    """Return requirements.txt's pins as {distribution (lower case): version}."""
    pins = {}
    for line in (REPO / "requirements.txt").read_text().splitlines():
        name, sep, version = line.split("#", 1)[0].strip().partition("==")
        if sep:
            pins[name.lower()] = version.split(";")[0].strip()
    return pins


def _rig_pc_section() -> str:
    text = (REPO / "README.md").read_text()
    return text.split("## On a rig PC with ROS 2 installed", 1)[1].split("\n## ", 1)[0]


def _readme_commands(program: str) -> list[list[str]]:
    """Return the README rig-PC lines that run ``program``, as words without the comment."""
    out = []
    for line in _rig_pc_section().splitlines():
        words = line.split("#", 1)[0].split()
        if words[:1] == [program]:
            out.append(words)
    return out


def _readme_pip_pins() -> dict[str, str]:
    """Return {distribution (lower case): version} of every README ``pip install`` line."""
    pins = {}
    for words in _readme_commands("pip"):
        assert words[1] == "install", words
        for item in words[2:]:
            name, sep, version = item.partition("==")
            assert sep, f"README pip line without a pin: {' '.join(words)}"
            pins[name.lower()] = version
    return pins


def test_pip_only_modules_are_pinned_alike_in_the_readme_and_requirements():
    readme, requirements = _readme_pip_pins(), _requirements()
    unused = sorted(set(PIP_ONLY) - _imports(REPO / "clutch_ros"))
    assert not unused, f"PIP_ONLY lists modules nothing imports: {unused}"
    wanted = {pin for pins in PIP_ONLY.values() for pin in pins}
    wanted |= {f"{pkg}=={requirements[pkg]}" for pkg in PIP_KEYS.values()}
    stated = {f"{name}=={version}" for name, version in readme.items()}
    assert stated == wanted, f"README pip lines {sorted(stated)} != wanted {sorted(wanted)}"
    for pin in sorted(wanted):
        name, _, version = pin.partition("==")
        assert requirements.get(name.lower()) == version, f"requirements.txt lacks {pin}"


def test_pip_keys_are_declared_and_pinned():
    declared = _declared()
    for key, package in PIP_KEYS.items():
        assert key in declared, f"package.xml lacks {key}"
        assert package in _readme_pip_pins(), f"README has no pinned pip line for {package}"
    undeclared = sorted(k for k in declared if k.endswith("-pip") and k not in PIP_KEYS)
    assert not undeclared, f"add these pip keys to PIP_KEYS: {undeclared}"


def test_readme_rosdep_and_colcon_commands_name_every_package():
    skip = {".venv", ".git", "build", "install", "log"}
    packages = sorted(
        "src/clutch_ros" + ("/" + str(p.parent.relative_to(REPO)) if p.parent != REPO else "")
        for p in REPO.rglob("package.xml") if not skip & set(p.relative_to(REPO).parts))
    assert packages == ["src/clutch_ros", "src/clutch_ros/msg_defs"], packages
    rosdep = _readme_commands("rosdep")
    colcon = _readme_commands("colcon")
    assert {w[1] for w in rosdep} >= {"update", "check", "install"}, rosdep
    assert any(w[1] == "build" for w in colcon), colcon
    for words in rosdep + colcon:
        if words[1] not in ("check", "install", "build"):
            continue
        option = "--paths" if words[0] == "colcon" else "--from-paths"
        at = words.index(option)
        named = []
        for word in words[at + 1:]:
            if word.startswith("-"):
                break
            named.append(word)
        assert sorted(named) == packages, (words, packages)
