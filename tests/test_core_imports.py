"""The core's modules import one another without a cycle, counting imports inside functions (a lazy import that
reaches back up is still a cycle in the design) and leaving out `if TYPE_CHECKING:` blocks (never run). Read from
source with `ast`, like tests/test_runs_imports.py does for the runs package, which this extends to all of i2pbench."""

import ast
from pathlib import Path

from test_runs_imports import cycle

CORE = Path(__file__).resolve().parents[1] / "i2pbench"
Graph = dict[str, set[str]]


def module_names(root: Path = CORE) -> dict[str, Path]:
    names = {}
    for path in root.rglob("*.py"):
        parts = ("i2pbench", *path.relative_to(root).with_suffix("").parts)
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return names


def _without_type_checking(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list):
            node.body = [c for c in body if not (isinstance(c, ast.If) and "TYPE_CHECKING" in ast.unparse(c.test))]
    return tree


def _target(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module if is_package else module.rsplit(".", 1)[0]
    for _ in range(node.level - 1):
        base = base.rsplit(".", 1)[0]
    return f"{base}.{node.module}" if node.module else base


def imports(module: str, path: Path, modules: set[str]) -> set[str]:
    """The core modules `module` imports: `from pkg import sub` counts as importing pkg.sub, not pkg."""
    found: set[str] = set()
    for node in ast.walk(_without_type_checking(ast.parse(path.read_text()))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = _target(module, path.name == "__init__.py", node)
            subs = {f"{base}.{alias.name}" for alias in node.names} & modules
            found |= subs or {base}
    return (found & modules) - {module}


def core_graph() -> Graph:
    names = module_names()
    return {name: imports(name, path, set(names)) for name, path in names.items()}


def test_type_checking_imports_are_left_out_and_function_level_ones_count(tmp_path):
    package = tmp_path / "i2pbench"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import x\n")
    (package / "b.py").write_text("def f():\n    from . import a\n")
    names = module_names(package)
    graph = {name: imports(name, path, set(names)) for name, path in names.items()}
    assert graph == {"i2pbench": set(), "i2pbench.a": set(), "i2pbench.b": {"i2pbench.a"}}


def test_the_core_has_no_import_cycle():
    graph = core_graph()
    assert len(graph) > 80 and "i2pbench.runs.worker" in graph  # the whole core was read
    assert "i2pbench.components" in graph["i2pbench.learned"]  # so components must never import learned back
    assert cycle(graph) == []
