"""The core's modules import one another without a cycle, counting every import wherever it is: inside a function (a
lazy import that reaches back up is still a cycle in the design) and under `if TYPE_CHECKING:` (an annotation that
names a module above is a dependency on it too). Read from source with `ast`, like tests/test_runs_imports.py does
for the runs package, which this extends to all of i2pbench. Each cycle is a strongly connected component of the
module graph, all of them reported at once."""

import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[1] / "i2pbench"
Graph = dict[str, set[str]]
# (importer, imported) edges the check leaves out, each with why; empty: the core has no deliberate back-edge
ALLOWED: dict[tuple[str, str], str] = {}


def module_names(root: Path = CORE) -> dict[str, Path]:
    names = {}
    for path in root.rglob("*.py"):
        parts = ("i2pbench", *path.relative_to(root).with_suffix("").parts)
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return names


def _target(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module if is_package else module.rsplit(".", 1)[0]
    for _ in range(node.level - 1):
        base = base.rsplit(".", 1)[0]
    return f"{base}.{node.module}" if node.module else base


def imports(module: str, path: Path, modules: set[str]) -> set[str]:
    """The core modules `module` imports anywhere in its source: `from pkg import sub` counts as importing pkg.sub,
    not pkg."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = _target(module, path.name == "__init__.py", node)
            subs = {f"{base}.{alias.name}" for alias in node.names} & modules
            found |= subs or {base}
    return (found & modules) - {module}


def core_graph(root: Path = CORE) -> Graph:
    names = module_names(root)
    return {name: imports(name, path, set(names)) for name, path in names.items()}


def cycles(graph: Graph) -> list[list[str]]:
    """Every group of modules that reach one another (Tarjan's strongly connected components of two or more, and
    a module importing itself), each sorted, in sorted order."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for child in sorted(graph.get(node, ())):
            if child not in index:
                visit(child)
                low[node] = min(low[node], low[child])
            elif child in stack:
                low[node] = min(low[node], index[child])
        if low[node] == index[node]:
            group = [stack.pop()]
            while group[-1] != node:
                group.append(stack.pop())
            if len(group) > 1 or node in graph.get(node, ()):
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def describe(group: list[str], graph: Graph) -> str:
    """A cycle as its edges, so the message says which imports to cut."""
    edges = [f"{a} -> {b}" for a in group for b in sorted(graph[a] & set(group))]
    return f"{len(group)} modules: " + "; ".join(edges)


def test_imports_under_type_checking_and_in_functions_count(tmp_path):
    package = tmp_path / "i2pbench"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import x\n")
    (package / "b.py").write_text("def f():\n    from . import a\n")
    (package / "c.py").write_text("import i2pbench.a\n")
    graph = core_graph(package)
    assert graph == {"i2pbench": set(), "i2pbench.a": {"i2pbench.b"}, "i2pbench.b": {"i2pbench.a"},
                     "i2pbench.c": {"i2pbench.a"}}  # fmt: skip
    assert cycles(graph) == [["i2pbench.a", "i2pbench.b"]]


def test_the_cycle_finder_reports_each_cycle_once_and_accepts_a_chain():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}, "f": {"a"}, "g": {"g"}}
    assert cycles(graph) == [["a", "b", "c"], ["d", "e"], ["g"]]
    assert cycles({"runner": {"executors", "jobs"}, "executors": {"worker", "jobs"}, "worker": {"jobs"}}) == []
    assert describe(["d", "e"], graph) == "2 modules: d -> e; e -> d"


def test_the_core_has_no_import_cycle():
    graph = core_graph()
    assert len(graph) > 80 and "i2pbench.runs.worker" in graph  # the whole core was read
    # so components must never import learned back
    assert "i2pbench.stages.components" in graph["i2pbench.stages.learned"]
    assert "i2pbench.corruptions.base" in graph["i2pbench.scoring.protocol"]  # seen under TYPE_CHECKING
    for importer, imported in ALLOWED:
        assert imported in graph[importer], f"ALLOWED names {importer} -> {imported}, which is gone: drop it"
        graph[importer].discard(imported)
    found = cycles(graph)
    assert not found, "import cycles in the core:\n" + "\n".join(describe(group, graph) for group in found)
