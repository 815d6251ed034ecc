"""One exception base, exceptions in errors modules (ARCHITECTURE.md, "Other rules").

* Every exception class of the package is defined in an ``errors.py`` (found by parsing every
  module: a class whose bases name an exception, or whose name ends in ``Error``); the modules
  they moved out of re-export them, which is an import, not a definition.
* Every exception defined in those modules derives from :class:`clutch_ros.errors.ClutchError`.
* The parse check can fail: a planted class outside an errors module is found.
"""

import ast
import importlib
from pathlib import Path

from clutch_ros.errors import ClutchError
from tests.conftest import REPO

PACKAGE = REPO / "clutch_ros"
BUILTIN_ERRORS = {name for name in dir(__builtins__ if isinstance(__builtins__, dict) else
                                       __builtins__) if name.endswith(("Error", "Exception"))}


def _exception_classes(source: str) -> list[str]:
    """Names of the classes in ``source`` that are exceptions by their bases or their name."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ClassDef):
            continue
        bases = {b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute)
                 else "" for b in node.bases}
        if node.name.endswith("Error") or any(
                b.endswith(("Error", "Exception")) or b in BUILTIN_ERRORS for b in bases):
            found.append(node.name)
    return found


def _misplaced(root: Path) -> dict[str, list[str]]:
    out = {}
    for path in sorted(root.rglob("*.py")):
        if path.name == "errors.py":
            continue
        names = _exception_classes(path.read_text())
        if names:
            out[str(path.relative_to(root))] = names
    return out


def test_every_exception_class_lives_in_an_errors_module():
    assert _misplaced(PACKAGE) == {}


def test_every_exception_of_the_errors_modules_derives_from_clutch_error():
    modules = sorted(PACKAGE.rglob("errors.py"))
    assert len(modules) >= 8  # the package's and its subpackages'
    checked = 0
    for path in modules:
        name = ".".join(path.relative_to(REPO).with_suffix("").parts)
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, type) and issubclass(value, BaseException) \
                    and value.__module__ == name:
                assert issubclass(value, ClutchError), f"{name}.{value.__name__}"
                checked += 1
    assert checked > 20


def test_the_parse_check_finds_a_planted_exception(tmp_path):
    (tmp_path / "errors.py").write_text("class GoodError(Exception):\n    pass\n")
    (tmp_path / "thing.py").write_text("import x\n\nclass Oops(ValueError):\n    pass\n\n"
                                       "class Plain:\n    pass\n\nclass BadError(x.Base):\n"
                                       "    pass\n")
    assert _misplaced(tmp_path) == {"thing.py": ["Oops", "BadError"]}
