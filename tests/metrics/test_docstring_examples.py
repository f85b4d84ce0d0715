"""Every public function and method of metrics/ shows an example in its docstring (run by pytest as a doctest)."""

from __future__ import annotations

import ast
import doctest
from pathlib import Path

import pytest

METRICS = Path(__file__).resolve().parents[2] / "metrics"


def public_functions(path: Path) -> list[tuple[str, ast.FunctionDef]]:
    """(qualified name, node) of the module's public functions and of its public classes' public methods
    (properties and cached properties are attributes, not functions: their examples are in the class's docstring)."""
    found = []
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
            found.append((node.name, node))
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            found += [(f"{node.name}.{item.name}", item) for item in node.body
                      if isinstance(item, ast.FunctionDef) and not item.name.startswith("_")
                      and not any(_is_property(d) for d in item.decorator_list)]
    return found


def _is_property(decorator: ast.expr) -> bool:
    name = decorator.attr if isinstance(decorator, ast.Attribute) else getattr(decorator, "id", "")
    return name in ("property", "cached_property")


MODULES = sorted(METRICS.glob("*.py"))


def test_the_walk_finds_the_functions_of_metrics():
    names = {name for path in MODULES for name, _ in public_functions(path)}
    assert {"upper_bound", "stack_stats", "RoiMean.value"} <= names
    assert not {"_moments", "StackStats.valid"} & names  # private; a property


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.name)
def test_every_public_function_has_an_example(path: Path):
    missing = [name for name, node in public_functions(path)
               if not doctest.DocTestParser().get_examples(ast.get_docstring(node) or "")]
    assert not missing, f"{path.name}: no '>>>' example in the docstring of {', '.join(missing)}"
