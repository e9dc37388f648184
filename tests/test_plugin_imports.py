"""Plugins reach the core through its public API only, and never import one another (issue 28, item 3).

Every `import` and `from ... import` in plugins/**/*.py is read with `ast` (nothing is imported): a module of the
`i2pbench` package may be `i2pbench.api`, the layer package `i2pbench.layers` or, in a plugin's tests, the
conformance kit `i2pbench.testing`; a plugin's package (`i2pbench_*` in a plugins/ folder) may be imported only from
its own folder. What is shared between methods lives in `i2pbench.layers`, so an edit to it moves the cache key of
every component that uses it (test_layers.py).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "plugins"
PUBLIC = ("i2pbench.api", "i2pbench.layers")
TESTS_ONLY = ("i2pbench.testing",)
# (file, module) imports the check lets through, each with why; none: a preset built on another plugin's method
# names it (`Row(size, swaps, method=..., confs=...)`), and the registry builds the row from its declaration
ALLOWED: set[tuple[str, str]] = set()


def plugin_packages() -> dict[str, str]:
    """top-level package name -> the plugins/ folder that holds it."""
    return {p.name: p.parent.name for p in PLUGINS.glob("*/i2pbench_*") if p.is_dir()}


def imported(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of each import in the file; relative imports stay inside their package."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            found.append((node.lineno, node.module or ""))
    return found


def problems(path: Path, packages: dict[str, str]) -> list[str]:
    rel = path.relative_to(PLUGINS).as_posix()
    folder, in_tests = rel.split("/")[0], "/tests/" in f"/{rel}"
    allowed = PUBLIC + (TESTS_ONLY if in_tests else ())
    out = []
    for line, module in imported(path):
        top = module.split(".")[0]
        if (rel, module) in ALLOWED:
            continue
        if top == "i2pbench" and not any(module == p or module.startswith(p + ".") for p in allowed):
            out.append(f"{rel}:{line} imports {module}, outside the public API ({', '.join(allowed)})")
        elif top in packages and packages[top] != folder:
            out.append(f"{rel}:{line} imports {module} from the plugin in plugins/{packages[top]}")
    return out


def test_plugins_import_only_the_public_api_and_no_other_plugin():
    packages = plugin_packages()
    assert {"i2pbench_edgeregnet", "i2pbench_corri2p", "i2pbench_deepi2p", "i2pbench_classic"} <= set(packages)
    files = sorted(PLUGINS.rglob("*.py"))
    assert len(files) > 50  # the walk sees every plugin
    found = [p for f in files for p in problems(f, packages)]
    assert not found, "\n".join(found)


def test_each_allowed_exception_is_still_there():
    """an exception nobody needs any more is removed from ALLOWED, not kept as a standing licence."""
    for rel, module in ALLOWED:
        assert module in {m for _, m in imported(PLUGINS / rel)}, f"{rel} no longer imports {module}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("from i2pbench.api import Frame\nfrom i2pbench.layers.pointnet2 import gather\n", []),
        ("from i2pbench.geometry.transforms import project\n", ["outside the public API"]),
        ("import i2pbench.training.batching\n", ["outside the public API"]),
        ("from i2pbench_corri2p.points import linear_mlp\n", ["from the plugin in plugins/corri2p"]),
        ("from i2pbench_deepi2p.labels import frustum_labels\n", []),  # its own package
        ("from .labels import frustum_labels\nimport numpy\n", []),
    ],
)
def test_the_check_names_what_it_refuses(tmp_path, monkeypatch, source, expected):
    """the rule itself, on files written into a fake deepi2p plugin folder."""
    monkeypatch.setitem(globals(), "PLUGINS", tmp_path)
    for name in ("deepi2p/i2pbench_deepi2p", "corri2p/i2pbench_corri2p"):
        (tmp_path / name).mkdir(parents=True)
    path = tmp_path / "deepi2p/i2pbench_deepi2p/fusion.py"
    path.write_text(source)
    found = problems(path, plugin_packages())
    assert len(found) == len(expected) and all(e in f for e, f in zip(expected, found, strict=True)), found
