import json
import re
import subprocess
import sys
import types

import numpy as np
import pytest
import toy_plugin

from i2pbench.api import Extractor2D, hookimpl
from i2pbench.errors import PluginError
from i2pbench.registry.build import build_registry
from i2pbench.registry.listing import components_of


@pytest.fixture
def isolated(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")


def test_components_are_registered_by_name_and_attributed(isolated):
    registry = build_registry((toy_plugin,))
    assert registry.component("extractor2d", "grid") is toy_plugin.GridPixels
    assert registry.owner("matcher", "truth") == "toy_plugin"
    assert "default" in registry.presets


def test_unknown_name_suggests_the_closest(isolated):
    registry = build_registry((toy_plugin,))
    with pytest.raises(PluginError, match=r"unknown extractor2d 'gird'; did you mean 'grid'\?"):
        registry.component("extractor2d", "gird")


def _other_plugin(cls_name: str):
    cls = type(cls_name, (Extractor2D,), {"name": "grid", "__call__": lambda self, frame: None})
    module = types.ModuleType("rival_plugin")

    @hookimpl
    def register_extractors_2d(register):
        register(cls)

    module.register_extractors_2d = register_extractors_2d
    return module


def test_name_clash_names_both_plugins(isolated):
    with pytest.raises(PluginError, match="'grid' is registered by both plugin 'toy_plugin' and 'rival_plugin'"):
        build_registry((toy_plugin, _other_plugin("RivalGrid")), strict=True)  # else skipped with a warning


def test_registering_a_non_component_is_refused(isolated):
    module = types.ModuleType("bad_plugin")

    @hookimpl
    def register_matchers(register):
        register(dict)

    module.register_matchers = register_matchers
    with pytest.raises(PluginError, match="bad_plugin.*does not subclass Matcher"):
        build_registry((module,), strict=True)


def _plugins_json(env: dict) -> list[dict]:
    out = subprocess.run(
        [sys.executable, "-m", "i2pbench.cli", "plugins", "--json"], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout)


def test_cli_lists_builtin_plugins_with_versions_and_components():
    rows = {r["plugin"]: r for r in _plugins_json({**_env()})}
    assert {"classic", "datasets", "edgeregnet"} <= set(rows)
    assert rows["classic"]["version"] == "0.1.0"
    assert all(r["distribution"] == "i2pbench" for r in rows.values())


def test_environment_variables_select_and_block_plugins():
    only = {r["plugin"] for r in _plugins_json({**_env(), "I2PBENCH_LOAD_PLUGINS": "classic"})}
    assert only == {"classic"}
    blocked = {r["plugin"] for r in _plugins_json({**_env(), "I2PBENCH_BLOCK_PLUGINS": "classic,edgeregnet"})}
    assert "classic" not in blocked and "edgeregnet" not in blocked and "datasets" in blocked


def _env() -> dict:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}


def _path_plugin(module_name: str, hook: str, *registrations: tuple[str, str]):
    """A plugin whose `hook` registers each (import path, name) without importing it."""
    module = types.ModuleType(module_name)

    @hookimpl
    def impl(register):
        for path, name in registrations:
            register(path, name=name)

    setattr(module, hook, impl)
    return module


LAZY_MODULE = """
import numpy as np
from i2pbench.api import Extractor2D, Keypoints2D


class Corners(Extractor2D):
    name = "corners"

    def __call__(self, frame):
        w, h = frame.image_size
        return Keypoints2D(np.array([[0, 0], [w - 1, h - 1]], np.float32))
"""


def test_a_component_registered_by_path_is_listed_unimported_and_imported_on_first_use(
    isolated, tmp_path, monkeypatch, request
):
    (tmp_path / "lazy_corners.py").write_text(LAZY_MODULE)
    monkeypatch.syspath_prepend(tmp_path)
    request.addfinalizer(lambda: sys.modules.pop("lazy_corners", None))
    plugin = _path_plugin("lazy_plugin", "register_extractors_2d", ("lazy_corners:Corners", "corners"))
    registry = build_registry((plugin,))
    assert components_of(registry, "lazy_plugin") == {"extractor2d": ["corners"]}
    assert "lazy_corners" not in sys.modules
    assert registry.component("extractor2d", "corners") is sys.modules["lazy_corners"].Corners
    assert registry.owner("extractor2d", "corners") == "lazy_plugin"


CLASSIC_STAGES = {
    "extractor2d": "lsd",
    "extractor3d": "depth+reflectance",
    "matcher": "oracle",
    "solver": "epnp-ransac",
}


def _registering(classes: tuple[type, ...]):
    @hookimpl
    def hook(register):
        for cls in classes:
            register(cls)

    return hook


def _eager_classic():
    """The classic plugin as it was before it registered by path: its classes imported and registered."""
    from i2pbench_classic import extract2d as e2
    from i2pbench_classic import extract3d as e3
    from i2pbench_classic import matchers, solvers

    module = types.ModuleType("eager_classic")
    module.register_extractors_2d = _registering(
        (e2.LSDExtractor, e2.CannyExtractor, e2.SobelExtractor, e2.RandomExtractor2D, e2.GridExtractor2D)
    )
    module.register_extractors_3d = _registering(
        (e3.DepthExtractor, e3.ReflectanceExtractor, e3.DepthReflectanceExtractor, e3.RandomExtractor3D)
    )
    module.register_matchers = _registering((matchers.CosineMatcher, matchers.OracleMatcher))
    module.register_pose_solvers = _registering((solvers.EPnPRansacSolver, solvers.PoseLibSolver))
    return module


def test_the_classic_plugin_by_path_gives_the_classes_and_results_an_eager_registration_gives(isolated):
    from i2pbench_classic import plugin as lazy_classic

    from i2pbench.stages.pipeline import Combination, Pipeline
    from i2pbench.testing import synthetic_frame

    lazy, eager = build_registry((lazy_classic,), strict=True), build_registry((_eager_classic(),), strict=True)
    for kind in ("extractor2d", "extractor3d", "matcher", "solver"):
        assert sorted(lazy.components[kind]) == sorted(eager.components[kind])
        assert all(lazy.component(kind, n) is eager.component(kind, n) for n in eager.components[kind])
    frame = synthetic_frame(3)
    lazy_run, eager_run = (Pipeline.build(r, Combination(CLASSIC_STAGES)).run(frame) for r in (lazy, eager))
    assert lazy_run.estimate.ok and np.array_equal(lazy_run.estimate.T, eager_run.estimate.T)
    assert (lazy_run.n_kp2d, lazy_run.n_kp3d) == (eager_run.n_kp2d, eager_run.n_kp3d)


def test_a_dataset_registered_by_path_resolves_to_its_class(isolated):
    registry = build_registry((_path_plugin("lazy_data", "register_datasets", ("toy_plugin:ToyDataset", "toy")),))
    assert registry.dataset("toy") is toy_plugin.ToyDataset


@pytest.mark.parametrize(
    ("path", "name", "error"),
    [
        ("no_such_module_xyz:Thing", "thing", "'thing' as 'no_such_module_xyz:Thing', which cannot be imported: "
         "ModuleNotFoundError"),
        ("toy_plugin:NoSuchClass", "thing", "cannot be imported: AttributeError"),
        ("toy_plugin:GridPixels", "grids", "toy_plugin:GridPixels as extractor2d 'grids', but its name is 'grid'"),
        ("toy_plugin:ToyDataset", "toy", "does not subclass Extractor2D"),
    ],
)  # fmt: skip
def test_a_bad_path_fails_on_use_naming_plugin_and_path_or_at_registration_when_strict(isolated, path, name, error):
    plugin = _path_plugin("paths", "register_extractors_2d", (path, name))
    registry = build_registry((plugin,))
    assert name in registry.components["extractor2d"]  # listed: nothing is imported while registering
    with pytest.raises(PluginError, match=f"plugin 'paths'.*{re.escape(error)}"):
        registry.component("extractor2d", name)
    with pytest.raises(PluginError, match=re.escape(error)):
        build_registry((plugin,), strict=True)


def test_a_path_needs_a_module_a_class_and_a_name(isolated):
    module = types.ModuleType("nameless")
    module.register_matchers = hookimpl(lambda register: register("toy_plugin:TruthMatcher"))
    with pytest.raises(PluginError, match="a path needs the form 'package.module:Class' and a name"):
        build_registry((module,), strict=True)


def test_one_class_registered_eagerly_and_by_path_is_no_clash_but_another_class_is(isolated):
    same = _path_plugin("by_path", "register_extractors_2d", ("toy_plugin:GridPixels", "grid"))
    registry = build_registry((toy_plugin, same), strict=True)
    assert registry.component("extractor2d", "grid") is toy_plugin.GridPixels
    other = _path_plugin("rival_path", "register_extractors_2d", ("toy_plugin:WrongShape", "grid"))
    with pytest.raises(PluginError, match="'grid' is registered by both plugin 'toy_plugin' and 'rival_path'"):
        build_registry((toy_plugin, other), strict=True)
