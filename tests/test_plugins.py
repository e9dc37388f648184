import json
import subprocess
import sys
import types

import pytest
import toy_plugin

from i2pbench.api import Extractor2D, hookimpl
from i2pbench.errors import PluginError
from i2pbench.plugins import build_registry


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
