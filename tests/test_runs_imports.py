"""The modules of `i2pbench.runs` import one another without a cycle: the worker code and the task types below, the
executors (the driver) on top. Read from source with `ast`, so an import inside a function counts."""

import ast
from pathlib import Path

RUNS = Path(__file__).resolve().parents[1] / "i2pbench" / "runs"
PACKAGE = "i2pbench.runs"
Graph = dict[str, set[str]]


def _absolute(node: ast.ImportFrom) -> str:
    """The module a `from ... import` names, for a module directly inside the runs package."""
    if not node.level:
        return node.module or ""
    base = PACKAGE.rsplit(".", node.level - 1)[0] if node.level > 1 else PACKAGE
    return f"{base}.{node.module}" if node.module else base


def imports(source: str, modules: set[str]) -> set[str]:
    """The runs modules that `source` (a module of the runs package) imports, wherever the statement is."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node)
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return found & modules


def runs_graph() -> Graph:
    paths = {f"{PACKAGE}.{p.stem}": p for p in RUNS.glob("*.py") if p.stem != "__init__"}
    return {name: imports(path.read_text(), set(paths)) for name, path in paths.items()}


def cycle(graph: Graph) -> list[str]:
    """One import cycle as a path that starts and ends at the same module, or [] when the graph has none."""
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> list[str]:
        if node in path:
            return path[path.index(node) :] + [node]
        if node in done:
            return []
        for child in sorted(graph.get(node, ())):
            if found := visit(child, path + [node]):
                return found
        done.add(node)
        return []

    return next((found for node in sorted(graph) if (found := visit(node, []))), [])


def test_the_parser_sees_relative_absolute_and_function_level_imports():
    modules = {f"{PACKAGE}.{m}" for m in ("a", "b", "c", "d")}
    source = "from .a import x\nfrom . import b\nimport i2pbench.runs.c\ndef f():\n    from ..runs.d import y\n"
    assert imports(source + "from ..pipeline import Pipeline\n", modules) == modules


def test_the_cycle_finder_names_a_cycle_and_accepts_a_chain():
    assert cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert cycle({"runner": {"executors", "jobs"}, "executors": {"worker", "jobs"}, "worker": {"jobs"}}) == []


def test_the_runs_modules_import_one_another_without_a_cycle():
    graph = runs_graph()
    assert cycle(graph) == []
    assert f"{PACKAGE}.ray_executor" in graph[f"{PACKAGE}.executors"]  # imported inside make_executor: seen
    for executor in ("executors", "ray_executor"):  # both run the one worker code
        assert f"{PACKAGE}.worker" in graph[f"{PACKAGE}.{executor}"]
