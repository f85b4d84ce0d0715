"""The packages depend one way: labctl (orchestration) on procedures, metrics, sim and drivers, never back;
procedures and metrics never on the simulation; and no module imports itself back through others (no cycle).

Read from the import statements of every module (static, so a lazy import inside a function counts too).
"""

import ast
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOWER = ("drivers", "procedures", "metrics", "sim")
PACKAGES = ("labctl", *LOWER)


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


def offenders(root: Path, package: str, forbidden: set[str]) -> list[str]:
    """Files of ``package`` under ``root`` that import any of the ``forbidden`` packages."""
    return sorted(str(p.relative_to(root)) for p in (root / package).rglob("*.py") if imported_packages(p) & forbidden)


@pytest.mark.parametrize("package", LOWER)
def test_lower_packages_do_not_import_the_orchestration(package: str) -> None:
    assert offenders(ROOT, package, {"labctl"}) == []


def test_drivers_stand_alone() -> None:
    """Device adapters need none of the project's other packages (they run against real hardware alone)."""
    assert offenders(ROOT, "drivers", {"labctl", "procedures", "metrics", "sim"}) == []


def test_every_labctl_subpackage_says_what_it_is_for() -> None:
    for init in (ROOT / "labctl").rglob("__init__.py"):
        if init.parent == ROOT / "labctl":
            continue
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
        assert doc and len(doc.splitlines()) == 1, f"{init.relative_to(ROOT)}: a one-line docstring"


@pytest.mark.parametrize("package", ["procedures", "metrics"])
def test_measurements_do_not_import_the_simulation(package: str) -> None:
    """Procedures and metrics work on real captures: the camera model they share with the simulator is
    metrics/optics.py. Procedures use metrics; metrics, pure functions, use no other package of the project."""
    forbidden = {"procedures": {"sim", "labctl"}, "metrics": set(PACKAGES) - {"metrics"}}[package]
    assert offenders(ROOT, package, forbidden) == []


def module_name(root: Path, path: Path) -> str:
    """Dotted name of the module in ``path`` (a package's ``__init__.py`` is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(root: Path, packages: tuple[str, ...] = PACKAGES) -> dict[str, set[str]]:
    """Module -> the project modules it imports, anywhere in its body.

    ``import a.b`` and ``from a.b import c`` point to module ``a.b``, or to ``a.b.c`` when ``c`` is a submodule;
    a name that is no module of the project points to the nearest enclosing one (``a`` for ``a.b`` if ``a.b`` is
    a class); imports from outside the project are left out.
    """
    paths = {module_name(root, p): p for package in packages for p in (root / package).rglob("*.py")}

    def resolve(name: str) -> str | None:
        while name and name not in paths:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for module, path in paths.items():
        targets: set[str | None] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                targets.update(resolve(alias.name) for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path}: relative import"
                base = node.module or ""
                targets.update(resolve(f"{base}.{alias.name}") for alias in node.names)
        graph[module] = {t for t in targets if t is not None and t != module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle [m, ..., m] through each group of modules that import one another (Tarjan's strongly connected
    components; the shortest cycle from the group's first module)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for target in sorted(graph[module]):
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            group = stack[stack.index(module):]
            del stack[stack.index(module):]
            if len(group) > 1:
                groups.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    cycles = []
    for group in sorted(groups):
        start, members = group[0], set(group)
        paths = {start: [start]}
        queue = [start]
        while queue:  # breadth first: the first way back to start is the shortest
            module = queue.pop(0)
            if start in graph[module]:
                cycles.append([*paths[module], start])
                break
            for target in sorted(graph[module] & members):
                if target not in paths:
                    paths[target] = [*paths[module], target]
                    queue.append(target)
    return cycles


def test_no_import_cycle() -> None:
    cycles = import_cycles(import_graph(ROOT))
    assert cycles == [], "import cycles:\n" + "\n".join(" -> ".join(cycle) for cycle in cycles)


def write_tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text, encoding="utf-8")
    return root


def test_checks_find_a_lazy_import_of_the_simulation(tmp_path: Path) -> None:
    root = write_tree(tmp_path, {
        "metrics/__init__.py": "",
        "metrics/fine.py": "import math\nfrom metrics import fine\n",
        "metrics/bad.py": "def f():\n    from sim.optics import Pinhole\n    return Pinhole\n",
        "sim/__init__.py": "",
        "sim/optics.py": "class Pinhole: ...\n",
    })
    assert offenders(root, "metrics", {"sim", "labctl"}) == [str(Path("metrics/bad.py"))]


def test_cycle_check_follows_lazy_and_from_imports_to_submodules(tmp_path: Path) -> None:
    root = write_tree(tmp_path, {
        "labctl/__init__.py": "def helper(): ...\n",
        "labctl/cli/__init__.py": "from labctl.cli.app import main\n",
        "labctl/cli/app.py": "from labctl import helper\n\ndef main():\n    from labctl.batch import sweep\n",
        "labctl/batch/__init__.py": "",
        "labctl/batch/sweep.py": "import labctl.cli.app\n",
        "sim/__init__.py": "",
        "sim/a.py": "from sim.b import thing\n",
        "sim/b.py": "import numpy\nthing = 1\n",
    })
    graph = import_graph(root)
    assert graph["labctl.cli.app"] == {"labctl", "labctl.batch.sweep"}  # a function of labctl, a submodule of batch
    assert graph["sim.a"] == {"sim.b"} and graph["sim.b"] == set()  # a name in sim.b; numpy is not the project's
    assert import_cycles(graph) == [["labctl.batch.sweep", "labctl.cli.app", "labctl.batch.sweep"]]
    (root / "labctl/batch/sweep.py").write_text("import labctl\n", encoding="utf-8")
    assert import_cycles(import_graph(root)) == []


#: the tests' own physics, the independent truth the simulator is checked against: none of it may come from the
#: simulator (or from labctl, which uses it), directly or through another module of tests/
INDEPENDENT_MODELS = ("tests/artefact_model.py", "tests/noise_model.py", "tests/reconcile/forward.py")


def borrowed_packages(root: Path, module: str) -> set[str]:
    """The top-level packages ``module`` (a path under ``root``) imports, following its imports of ``tests.*``."""
    seen: set[Path] = set()
    found: set[str] = set()
    pending = [root / module]
    while pending:
        path = pending.pop()
        if path in seen or not path.exists():
            continue
        seen.add(path)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for name in names:
                found.add(name.split(".")[0])
                if name.startswith("tests."):
                    pending.append(root / (name.replace(".", "/") + ".py"))
    return found


@pytest.mark.parametrize("module", INDEPENDENT_MODELS)
def test_the_tests_physics_owes_nothing_to_the_simulator(module: str) -> None:
    assert borrowed_packages(ROOT, module) & {"sim", "labctl"} == set()


def test_independence_check_follows_the_tests_own_imports(tmp_path: Path) -> None:
    root = write_tree(tmp_path, {
        "tests/model.py": "import math\nfrom tests.helper import law\n",
        "tests/helper.py": "def law():\n    from sim.tof import range_noise_mm\n    return range_noise_mm\n",
        "tests/clean.py": "import numpy as np\nfrom tests import other\n",
    })
    assert "sim" in borrowed_packages(root, "tests/model.py")
    assert borrowed_packages(root, "tests/clean.py") == {"numpy", "tests"}


#: modules that act on or fit effects through their declarations (sim/effects/<name>.py), never by name
EFFECT_NEUTRAL = ("labctl/reconcile/candidates.py", "sim/tof.py", "sim/stereo.py")
#: where no effect fact may be stated: the simulator outside its effect library, and reconcile
EFFECT_FREE = ("sim", "labctl/reconcile")
EFFECT_LIBRARY = "sim/effects"
#: parameter names reconcile fits that are also words of another vocabulary of the project (what they mean there)
SHARED_WORDS = {
    "offset_mm": "a target's placement on the board or plate (sim/scenes/targets.py)",
    "distance_mm": "a step's camera-wall distance (procedures, run files, scene builders)",
    "reflectance": "a surface's reflectance where a ray hits it (sim/render.py)",
}
#: a fraction's range, everybody's: not taken for a parameter's stated bounds
UNIT_INTERVAL = (0.0, 1.0)


def effect_names() -> set[str]:
    from sim.effects import EFFECTS

    return set(EFFECTS)


def fitted_names() -> set[str]:
    """The names of the parameters reconcile fits or sets (``Observed.fitted``, ``fixed``, the corner fit's
    variants)."""
    from sim.effects import EFFECTS

    names: set[str] = set()
    for effect in EFFECTS.values():
        if effect.observed is not None:
            names.update(effect.observed.fitted, effect.observed.fixed)
            if effect.observed.corners is not None:
                names.update(*effect.observed.corners.variants)
    return names


def effect_literals() -> set[str]:
    """Every effect's name and the names of the parameters reconcile fits or sets."""
    return effect_names() | fitted_names()


def declared_bounds() -> dict[tuple[float, float], str]:
    """Every (lower, upper) pair an effect declares, to the parameter it bounds: its fields' valid ranges (both
    ends finite), its solver bounds and its corner fit's bounds; the unit interval left out."""
    from sim.effects import EFFECTS, valid_range

    found: dict[tuple[float, float], str] = {}
    for effect in EFFECTS.values():
        for key in effect.params.model_fields:
            found[valid_range(effect.params, key)] = f"{effect.name}.{key}"
        observed = effect.observed
        if observed is not None:
            found.update({(float(lo), float(hi)): f"{effect.name}.{key}"
                          for key, (lo, hi) in observed.solver_bounds.items()})
            if observed.corners is not None:
                c = observed.corners
                found.update({(lo, hi): f"{effect.name}.{key}" for key, lo, hi in zip(c.keys, c.lower, c.upper)})
    return {pair: name for pair, name in found.items() if all(map(math.isfinite, pair)) and pair != UNIT_INTERVAL}


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


def effect_free_modules(root: Path) -> list[Path]:
    """The modules of ``EFFECT_FREE`` under ``root``, the effect library left out."""
    library = root / EFFECT_LIBRARY
    return sorted(p for folder in EFFECT_FREE for p in (root / folder).rglob("*.py")
                  if library not in p.parents)


def _number(node: ast.AST) -> float | None:
    """The value of a numeric literal (signed), else None."""
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _number(node.operand)
        return None if value is None else (-value if isinstance(node.op, ast.USub) else value)
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        return float(node.value)
    return None


def _numbers(node: ast.AST) -> list[float | None]:
    """The numbers a literal, or a call, list or tuple of them (a call's arguments), holds; None for anything else."""
    value = _number(node)
    if value is not None:
        return [value]
    if isinstance(node, ast.Call):
        return [n for arg in node.args for n in _numbers(arg)] if node.args and not node.keywords else [None]
    if isinstance(node, (ast.List, ast.Tuple)):
        return [n for elt in node.elts for n in _numbers(elt)]
    return [None]


def _bound(node: ast.AST) -> float | None:
    """The number an end of a bound pair states: a numeric literal, or a call, list or tuple of literals all equal
    to one number (``np.array([10.0, 10.0])``)."""
    numbers = set(_numbers(node))
    return numbers.pop() if len(numbers) == 1 else None


def stated_bounds(source: str) -> set[tuple[float, float]]:
    """The (lower, upper) pairs a module writes out: two-element tuples and lists (``(-0.5, 0.5)``,
    ``(np.array([-0.5]), np.array([0.5]))``) and chained comparisons (``10.0 <= v <= 170.0``)."""
    pairs: set[tuple[float, float]] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Tuple, ast.List)) and len(node.elts) == 2:
            pairs.add((_bound(node.elts[0]), _bound(node.elts[1])))
        elif isinstance(node, ast.Compare) and len(node.ops) == 2:
            pairs.add((_number(node.left), _number(node.comparators[1])))
    return {pair for pair in pairs if None not in pair}


def stated_effect_facts(root: Path, names: set[str], parameters: set[str],
                        bounds: dict[tuple[float, float], str]) -> list[str]:
    """What the modules of ``EFFECT_FREE`` under ``root`` state of the effects: a string literal equal to an
    effect's name or to a fitted parameter's name (``SHARED_WORDS`` left out), a declared bound pair."""
    found = []
    for path in effect_free_modules(root):
        source = path.read_text(encoding="utf-8")
        where = path.relative_to(root).as_posix()
        literals = string_literals(source)
        found += [f"{where}: effect name {n!r}" for n in sorted(literals & names)]
        found += [f"{where}: parameter name {n!r}" for n in sorted(literals & (parameters - set(SHARED_WORDS)))]
        found += [f"{where}: bounds {pair} of {bounds[pair]}" for pair in sorted(stated_bounds(source) & set(bounds))]
    return found


def test_effect_facts_are_stated_only_in_their_modules() -> None:
    """Adding an effect is adding its module: nothing of the simulator outside sim/effects/ and nothing of
    reconcile states an effect's facts, so none holds a copy that could disagree.

    The rule, read from the syntax tree of every module of ``EFFECT_FREE`` (the effect library left out):

    * no string literal equals an effect's name (the code reaches an effect through its declaration's hooks and
      fields, or its module's ``EFFECT.name``);
    * no string literal equals the name of a parameter reconcile fits or sets (``Observed.fitted``, ``fixed``,
      the corner fit's variants), but for the few that are also words of another vocabulary (``SHARED_WORDS``,
      each with its meaning there): a whole string counts, so text that mentions an effect is free;
    * no two-element tuple or list, and no chained comparison, states the (lower, upper) pair of a bound an
      effect declares (a field's valid range, its solver bounds, its corner fit's bounds); the unit interval,
      a fraction's range everywhere, is not taken for a bound.
    """
    assert stated_effect_facts(ROOT, effect_names(), fitted_names(), declared_bounds()) == []


EFFECT_TREE = {
    "sim/__init__.py": "",
    "sim/effects/range_scale.py": 'NAME = "range_scale"\nBOUNDS = (-0.1, 0.1)\n',
    "sim/fine.py": '"""Mentions range_scale in text."""\nSPAN = (0.0, 1.0)\nKEY = "offset_mm"\nPAIR = (-0.1, 0.2)\n',
    "labctl/reconcile/fine.py": "def f(v):\n    return 0.0 <= v <= 1.0\n",
    "labctl/run/elsewhere.py": 'NAME = "range_scale"\n',
}


@pytest.mark.parametrize("violation, found", [
    ('ACTS = {"range_scale": 1}\n', "effect name 'range_scale'"),
    ('def period(p):\n    return p.get("tau_s", 600.0)\n', "parameter name 'tau_s'"),
    ("LIMITS = (np.array([-0.1]), np.array([0.1]))\n", "bounds (-0.1, 0.1) of {owner}"),
    ("def ok(v):\n    return -0.1 <= v <= 0.1\n", "bounds (-0.1, 0.1) of {owner}"),
])
@pytest.mark.parametrize("module", ["sim/bad.py", "labctl/reconcile/bad.py"])
def test_fact_check_finds_an_effect_fact_stated_outside_its_module(tmp_path: Path, module: str, violation: str,
                                                                   found: str) -> None:
    root = write_tree(tmp_path, EFFECT_TREE)
    check = (effect_names(), fitted_names(), declared_bounds())
    assert stated_effect_facts(root, *check) == []
    write_tree(root, {module: violation})
    owner = check[2].get((-0.1, 0.1), "")  # range_scale.scale, or another effect's parameter with the same bounds
    assert stated_effect_facts(root, *check) == [f"{module}: {found.format(owner=owner)}"]


def test_the_run_does_not_depend_on_its_console() -> None:
    """labctl.console watches a run through labctl.run.observer; labctl.run never imports the console."""
    importers = []
    for path in (ROOT / "labctl" / "run").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            modules = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                       else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(m == "labctl.console" or m.startswith("labctl.console.") for m in modules):
                importers.append(str(path.relative_to(ROOT)))
    assert importers == []
