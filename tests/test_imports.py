"""Which way imports go, read from the source with `ast` (nothing is imported): library rooms never import the
command-line tools or the experiment runner, geometry and nn stay below the rooms that use them, and the modules
of the package import each other without cycles."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from conftest import ROOT

SRC = ROOT / "src"
PACKAGE = "deepcurrents"
LIBRARY_ROOMS = ("geometry", "nn", "data", "models", "baselines", "eval", "losses", "errors")
APP_ROOMS = ("api", "cli", "experiments")
# room -> rooms (or outside packages) it must not import, on top of APP_ROOMS for library rooms
FORBIDDEN_BELOW = {
    "geometry": ("nn", "data", "models", "baselines", "eval", "losses", "lightning"),
    "nn": ("data", "models", "baselines", "eval", "lightning"),
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    return {module_name(p): p for p in sorted((SRC / PACKAGE).rglob("*.py"))}


def room(name: str) -> str:
    """The room of a module: deepcurrents.eval.metrics -> eval, deepcurrents.losses -> losses."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else ""


def is_type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def imported_names(node: ast.Import | ast.ImportFrom, module: str, is_package: bool, known: set[str]) -> list[str]:
    """The absolute names an import statement loads: a submodule where `from X import Y` names one, else X."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    base = node.module or ""
    if node.level:  # relative: resolve against the importing module's package
        package = module.split(".") if is_package else module.split(".")[:-1]
        package = package[: len(package) - (node.level - 1)]
        base = ".".join([*package, base] if base else package)
    out = []
    for alias in node.names:
        sub = f"{base}.{alias.name}"
        out.append(sub if sub in known else base)
    return out


def collect_imports(path: Path, module: str, known: set[str]) -> tuple[list[tuple[str, int]], list[str]]:
    """(every import with its line, the imports run when the module is loaded: module level, outside functions
    and `TYPE_CHECKING` blocks)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    everywhere: list[tuple[str, int]] = []
    at_load: list[str] = []

    def walk(node: ast.AST, loading: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                names = imported_names(child, module, is_package, known)
                everywhere.extend((n, child.lineno) for n in names)
                if loading:
                    at_load.extend(names)
                continue
            deferred = isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) or is_type_checking(
                child
            )
            walk(child, loading and not deferred)

    walk(tree, True)
    return everywhere, at_load


@pytest.fixture(scope="module")
def graph() -> dict[str, tuple[list[tuple[str, int]], list[str]]]:
    known = set(modules())
    return {name: collect_imports(path, name, known) for name, path in modules().items()}


def in_room(target: str, forbidden: str) -> bool:
    if forbidden == "lightning":
        return target.split(".")[0] in ("lightning", "pytorch_lightning")
    return target == f"{PACKAGE}.{forbidden}" or target.startswith(f"{PACKAGE}.{forbidden}.")


def test_the_graph_sees_every_room(graph):
    # guards the test itself: a broken walk would find no imports and pass everything below
    assert {room(m) for m in graph} >= {*LIBRARY_ROOMS, *APP_ROOMS}
    assert any(in_room(t, "geometry") for t, _ in graph[f"{PACKAGE}.nn.current"][0])
    assert any(in_room(t, "lightning") for t in graph[f"{PACKAGE}.models.base"][1])


def violations(graph, rule) -> list[str]:
    """Every import for which ``rule(module, target)`` is true, one line each."""
    return [f"{module} imports {target} (line {line})" for module, (everywhere, _) in graph.items()
            for target, line in everywhere if rule(module, target)]


def test_library_rooms_do_not_import_apps_or_experiments(graph):
    bad = violations(graph, lambda m, t: room(m) in LIBRARY_ROOMS and any(in_room(t, app) for app in APP_ROOMS))
    assert not bad, "library rooms must not import cli/ or experiments/:\n" + "\n".join(bad)


@pytest.mark.parametrize("lower", sorted(FORBIDDEN_BELOW))
def test_lower_rooms_do_not_import_upper_ones(graph, lower):
    bad = violations(graph, lambda m, t: room(m) == lower and any(in_room(t, up) for up in FORBIDDEN_BELOW[lower]))
    assert not bad, f"{lower} must not import {', '.join(FORBIDDEN_BELOW[lower])}:\n" + "\n".join(bad)


# docs/architecture.md: a room imports only from rooms on lower layers
LAYERS = {"errors": 1, "losses": 1, "geometry": 2, "nn": 3, "data": 3, "eval": 3, "models": 4, "baselines": 5,
          "experiments": 6, "api": 7, "cli": 7, "": 8}


def test_every_room_has_a_layer(graph):
    assert {room(m) for m in graph} <= set(LAYERS), "a new room: give it a layer here and in docs/architecture.md"


def test_rooms_import_only_from_lower_layers(graph):
    def against(module: str, target: str) -> bool:
        return (target.startswith(f"{PACKAGE}.") and room(target) != room(module)
                and LAYERS.get(room(target), 99) >= LAYERS.get(room(module), 0))

    bad = violations(graph, against)
    assert not bad, "imports against the layers of docs/architecture.md:\n" + "\n".join(bad)


def find_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (or a self-loop), by Tarjan's algorithm."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
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
            if len(component) > 1 or v in edges.get(v, ()):
                cycles.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return cycles


def test_cycle_finder_finds_a_cycle_and_only_cycles():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b"}, "b": {"c"}, "d": {"a", "c"}}) == []
    assert find_cycles({"a": {"a"}}) == [["a"]]


def test_no_import_cycles_between_modules(graph):
    edges = {
        module: {t for t, _ in everywhere if t in graph and t != module}
        for module, (everywhere, _) in graph.items()
    }
    cycles = find_cycles(edges)
    assert not cycles, "import cycles (modules importing each other, at load time or inside functions):\n" + "\n".join(
        " <-> ".join(c) for c in cycles
    )
