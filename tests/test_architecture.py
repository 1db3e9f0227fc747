"""The package's structure: families in layers, no import circles, the edge apart from the core, boards behind one
interface. Read from the source (every import counts, function-local ones too), nothing is run."""

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "beamdrop_jax"

# The pipeline, lowest first: a module imports its own family and the families before it, never one after it.
LAYERS = ("_common", "_board", "_scene", "_impact", "_response", "_studies")
EDGE = ("cli", "_plots", "_bench", "_peers")  # they import the core; the core imports none of them
# The one lazy import the package allows (a function-local import, which closes no circle at import time):
# `Scene.default()` reads the embedded default scene through the scene files, which build scenes.
LAZY = {("_scene.containers", "_scene.file")}


def _modules() -> dict[str, Path]:
    return {".".join(p.relative_to(PACKAGE).with_suffix("").parts): p for p in PACKAGE.rglob("*.py")
            if p.name != "__init__.py"}


def _imports(name: str, path: Path) -> set[str]:
    """The package modules `name` imports, at any depth of its code."""
    here = name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = here[: len(here) - node.level + 1]
            target = base + (node.module.split(".") if node.module else [])
            candidates = [".".join(target + [alias.name]) for alias in node.names] + [".".join(target)]
            found.update(c for c in candidates if c in _modules())
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            module = node.module if isinstance(node, ast.ImportFrom) else None
            for alias in ([ast.alias(module)] if module else node.names):
                if alias.name.startswith("beamdrop_jax."):
                    rest = alias.name.removeprefix("beamdrop_jax.")
                    if rest in _modules():
                        found.add(rest)
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    return {name: _imports(name, path) for name, path in _modules().items()}


def _family(name: str) -> str:
    return name.split(".")[0]


def test_no_import_circles():
    graph = {name: {t for t in targets if (name, t) not in LAZY} for name, targets in _graph().items()}
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, f"import circles: {circles}"


def test_families_import_only_earlier_layers_and_never_the_edge():
    wrong = []
    for name, targets in _graph().items():
        family = _family(name)
        for target in targets:
            if (name, target) in LAZY:
                continue
            other = _family(target)
            if family in LAYERS and (other in EDGE or LAYERS.index(other) > LAYERS.index(family)):
                wrong.append(f"{name} -> {target}")
    assert not wrong, "imports against the pipeline's direction: " + ", ".join(sorted(wrong))


def test_the_common_family_imports_nothing_else_of_the_package():
    wrong = [f"{n} -> {t}" for n, ts in _graph().items() if _family(n) == "_common" for t in ts
             if _family(t) != "_common"]
    assert not wrong, wrong


def test_board_type_switches_only_in_the_board_family():
    """Nothing downstream asks which board it holds: `isinstance` against a board class appears in the board
    family only, and elsewhere at most three input checks (each says so in a comment), none a dispatch."""
    board_classes = re.compile(r"isinstance\([^)]*\b(Plate|PlateModes|Board|BeamModes|AbstractBoard|AbstractModes)\b")
    found = [f"{p.relative_to(PACKAGE)}:{i}" for name, p in _modules().items() if _family(name) != "_board"
             for i, line in enumerate(p.read_text().splitlines(), 1) if board_classes.search(line)]
    checks = [f for f in found if "# input check" in (PACKAGE / f.split(":")[0]).read_text().splitlines()[int(f.split(":")[1]) - 1]]
    assert len(checks) <= 3 and found == checks, found


def test_modules_and_functions_stay_small():
    big, long = [], []
    for name, path in _modules().items():
        source = path.read_text()
        if source.count("\n") > 700:
            big.append(name)
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 150:
                long.append(f"{name}.{node.name}")
    assert not big and not long, (big, long)


def test_the_core_imports_at_the_top():
    """Function-local imports hide circles: the core has one, documented (`LAZY`); the edge (the CLI, figures,
    benchmark) may import late for the command line's start-up time."""
    late = []
    for name, path in _modules().items():
        if _family(name) not in LAYERS:
            continue
        for function in ast.walk(ast.parse(path.read_text())):
            if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(function):
                    if isinstance(node, ast.ImportFrom) and node.level:
                        target = ".".join(name.split(".")[:-node.level] + [node.module or ""]).strip(".")
                        if (name, target) not in LAZY:
                            late.append(f"{name}.{function.name}: {target}")
    assert not late, late
