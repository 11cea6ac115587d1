"""The clray package's import graph (docs/architecture.md): every module in a layer, no import
from a lower layer to a higher one, and no import loop. Imports are read with ast, inside
functions too: a deferred import is still a dependency."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "clray"

# Lowest first. A module belongs to the first layer with a prefix that names it or a package
# above it; within a layer imports go either way.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("clray.errors", "clray.metrics", "clray.knobs", "clray.output", "clray.vectors",
              "clray.host_memory")),
    ("shapes/lights", ("clray.shapes", "clray.lights")),
    ("scene/accel", ("clray.scene", "clray.accel")),
    ("device", ("clray.device",)),
    ("render/cli", ("clray", "clray.render", "clray.image_io", "clray.cli", "clray.__main__",
                    "clray.distributed", "clray.sequence", "clray.study", "clray.reference")),
]

def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports(path: Path) -> set[str]:
    """The clray modules a file imports: `from a import b` names a.b where that is a module."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "clray")
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.split(".")[0] == "clray":
            subs = [f"{node.module}.{a.name}" for a in node.names]
            found.update(s for s in subs if _is_module(s))
            if not all(_is_module(s) for s in subs):
                found.add(node.module)
    return found


def import_graph() -> dict[str, set[str]]:
    graph = {_module_name(p): _imports(p) for p in PACKAGE.rglob("*.py")}
    return {module: deps - {module} for module, deps in graph.items()}


def layer_of(module: str) -> int | None:
    best = None
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                if best is None or len(prefix) > best[0]:
                    best = (len(prefix), index)
    return None if best is None else best[1]


def upward_imports(graph: dict[str, set[str]]) -> set[tuple[str, str]]:
    return {(module, dep) for module, deps in graph.items() for dep in deps
            if layer_of(dep) > layer_of(module)}


def loops(graph: dict[str, set[str]]) -> list[set[str]]:
    """The graph's strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(component)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_is_read() -> None:
    graph = import_graph()
    assert "clray.device.launch" in graph["clray.render"]
    assert "clray.accel.bvh" in graph["clray.device.bvh_builder"]
    assert len(graph) > 30


def test_every_module_has_a_layer() -> None:
    assert [m for m in import_graph() if layer_of(m) is None] == []


def test_no_import_from_a_lower_layer_to_a_higher_one() -> None:
    assert upward_imports(import_graph()) == set()


def test_no_import_loops() -> None:
    assert loops(import_graph()) == []


def test_the_checks_can_fail() -> None:
    graph = {"clray.scene.model": {"clray.device.pack"}, "clray.device.pack": {"clray.render"},
             "clray.render": {"clray.scene.model"}}
    assert upward_imports(graph) == {("clray.scene.model", "clray.device.pack"),
                                     ("clray.device.pack", "clray.render")}
    assert loops(graph) == [set(graph)]
