"""The packages depend one way: labctl (orchestration) on procedures, metrics, sim and drivers, never back.

Read from the import statements of every module (static, so a lazy import inside a function counts too).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOWER = ("drivers", "procedures", "metrics", "sim")


def imported_packages(path: Path) -> set[str]:
    """Top-level names of every module ``path`` imports (absolute imports only; the project uses no relative ones)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"
            names.add((node.module or "").split(".")[0])
    return names


@pytest.mark.parametrize("package", LOWER)
def test_lower_packages_do_not_import_the_orchestration(package: str) -> None:
    offenders = sorted(str(p.relative_to(ROOT)) for p in (ROOT / package).rglob("*.py") if "labctl" in imported_packages(p))
    assert offenders == []


def test_drivers_stand_alone() -> None:
    """Device adapters need none of the project's other packages (they run against real hardware alone)."""
    offenders = sorted(
        str(p.relative_to(ROOT))
        for p in (ROOT / "drivers").rglob("*.py")
        if imported_packages(p) & {"labctl", "procedures", "metrics", "sim"}
    )
    assert offenders == []


def test_every_labctl_subpackage_says_what_it_is_for() -> None:
    for init in (ROOT / "labctl").rglob("__init__.py"):
        if init.parent == ROOT / "labctl":
            continue
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
        assert doc and len(doc.splitlines()) == 1, f"{init.relative_to(ROOT)}: a one-line docstring"


#: modules that act on or fit effects through their declarations (sim/effects/<name>.py), never by name
EFFECT_NEUTRAL = ("labctl/reconcile/candidates.py", "sim/tof.py", "sim/stereo.py")


def effect_literals() -> set[str]:
    """Every effect's name and the names of the parameters reconcile fits or sets (``Observed``)."""
    from sim.effects import EFFECTS

    names = set(EFFECTS)
    for effect in EFFECTS.values():
        if effect.observed is not None:
            names.update(effect.observed.fitted, effect.observed.fixed)
    return names


def string_literals(source: str) -> set[str]:
    """The string constants of a module (docstrings included: only a whole string equal to a name counts)."""
    return {node.value for node in ast.walk(ast.parse(source)) if isinstance(node, ast.Constant)
            and isinstance(node.value, str)}


@pytest.mark.parametrize("module", EFFECT_NEUTRAL)
def test_effect_facts_stay_in_their_modules(module: str) -> None:
    """An effect's name, parameters and bounds are stated once, in its own module: the sensors call its hooks
    and reconcile builds its candidate from its declaration, so neither names an effect or a fitted parameter."""
    found = string_literals((ROOT / module).read_text(encoding="utf-8")) & effect_literals()
    assert found == set(), f"{module} names {sorted(found)}"
