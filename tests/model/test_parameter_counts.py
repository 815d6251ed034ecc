"""No function or method of the model takes more than 10 parameters (issue 25).

A long parameter list passes a model's state by hand: the compiled kernel takes records
(namedtuples of arrays and scalars, :mod:`clutch_ros.model.kernel`) instead, so one new model
input is one field, not six signatures. Counted: positional and keyword parameters,
``*args`` and ``**kwargs`` as one each, ``self``/``cls`` of methods excluded; every function
of every module, nested ones and lambdas included (ast), so a compiled function counts as
its Python source.
"""

import ast
import inspect
from pathlib import Path

import clutch_ros.model as model_pkg

MAX_PARAMETERS = 10
MODEL_DIR = Path(model_pkg.__file__).resolve().parent


def parameter_count(node) -> int:
    """Return the parameters of a FunctionDef/Lambda, ``self``/``cls`` of a method excluded."""
    a = node.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def _functions():
    for path in sorted(MODEL_DIR.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                yield path, node


def test_counter_counts_what_it_should():
    tree = ast.parse("def f(a, b=1, *c, d, e=2, **g): pass\n"
                     "class K:\n    def m(self, x, /, y): pass\n")
    f, k = tree.body
    assert parameter_count(f) == 6 and parameter_count(k.body[0]) == 2
    # the same count as inspect for a real function of the model
    from clutch_ros.model.simulate import simulate
    node = next(n for p, n in _functions()
                if p.name == "simulate.py" and getattr(n, "name", "") == "simulate")
    assert parameter_count(node) == len(inspect.signature(simulate).parameters)


def test_no_model_function_takes_more_than_ten_parameters():
    seen = 0
    too_many = []
    for path, node in _functions():
        seen += 1
        n = parameter_count(node)
        if n > MAX_PARAMETERS:
            too_many.append(f"{path.name}:{node.lineno} {getattr(node, 'name', 'lambda')} "
                            f"takes {n}")
    assert seen > 300  # the walk did reach the model's functions
    assert not too_many, too_many
