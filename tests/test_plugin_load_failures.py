"""A plugin that fails to import, or clashes with a built-in, is reported and skipped: every command keeps working,
`i2pbench plugins` lists it as failed, and the built-in keeps its name."""

import json
import types

import plugin_dists
import pytest
import toy_plugin

from i2pbench.api import Extractor2D, hookimpl
from i2pbench.errors import PluginError
from i2pbench.registry.build import build_registry

BROKEN = {"broken": "i2pbench_no_such_module", "rival": "fault_plugin:rival"}


@pytest.fixture
def site(tmp_path, monkeypatch):
    """An installed distribution offering a plugin that does not import and one whose `lsd` clashes with classic's."""
    site = plugin_dists.install(tmp_path / "site", BROKEN)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "broken,classic,rival")
    return site


def test_a_plugin_that_fails_to_import_is_reported_skipped_and_listed(site, capsys):
    registry = build_registry()
    info = {i.name: i for i in registry.plugins}
    assert info["broken"].failed and not info["classic"].failed
    assert "No module named 'i2pbench_no_such_module'" in info["broken"].error
    assert info["broken"].distribution == "i2pbench-test-plugins" and info["broken"].version == "0.1"
    assert "lsd" in registry.components["extractor2d"]  # the rest loaded
    warning = next(line for line in capsys.readouterr().err.splitlines() if "'broken'" in line)
    assert warning.startswith("i2pbench: warning: plugin 'broken' failed to import")
    assert "ModuleNotFoundError" in warning and "I2PBENCH_BLOCK_PLUGINS=broken" in warning


def test_a_plugin_clashing_with_a_built_in_is_skipped_whole_and_the_built_in_kept(site, capsys):
    registry = build_registry()
    assert registry.owner("extractor2d", "lsd") == "classic"
    assert "rival-only" not in registry.components["extractor2d"]  # nothing of a refused plugin is kept
    rival = next(i for i in registry.plugins if i.name == "rival")
    assert rival.error == "extractor2d name 'lsd' is registered by both plugin 'classic' and 'rival'"
    err = capsys.readouterr().err
    assert "plugin 'rival' could not register: extractor2d name 'lsd'" in err
    assert "I2PBENCH_BLOCK_PLUGINS=rival" in err


def test_blocking_the_failed_plugins_silences_the_warnings(site, monkeypatch, capsys):
    monkeypatch.setenv("I2PBENCH_BLOCK_PLUGINS", "broken,rival")
    assert {i.name for i in build_registry().plugins} == {"classic"}
    assert capsys.readouterr().err == ""


def test_strict_loading_raises_instead(site):
    with pytest.raises(PluginError, match="plugin 'broken' failed to import"):
        build_registry(strict=True)


def test_between_two_third_party_plugins_the_later_one_is_skipped(monkeypatch, capsys):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    rival = types.ModuleType("rival_grid")

    @hookimpl
    def register_extractors_2d(register):
        register(type("RivalGrid", (Extractor2D,), {"name": "grid", "__call__": lambda self, frame: None}))

    rival.register_extractors_2d = register_extractors_2d
    registry = build_registry((toy_plugin, rival))
    assert registry.component("extractor2d", "grid") is toy_plugin.GridPixels
    assert [i.name for i in registry.plugins if i.failed] == ["rival_grid"]
    assert "'grid' is registered by both plugin 'toy_plugin' and 'rival_grid'" in capsys.readouterr().err


def test_a_plugin_whose_hook_raises_is_skipped(monkeypatch, capsys):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    module = types.ModuleType("raising_plugin")

    @hookimpl
    def register_matchers(register):
        raise RuntimeError("config file missing")

    module.register_matchers = register_matchers
    registry = build_registry((toy_plugin, module))
    failed = next(i for i in registry.plugins if i.name == "raising_plugin")
    assert failed.error == "raised RuntimeError: config file missing"
    assert "truth" in registry.components["matcher"]  # the toy plugin's registrations stand


def test_the_plugins_command_works_and_lists_the_failed_plugins(site, tmp_path):
    env = plugin_dists.env(site, I2PBENCH_LOAD_PLUGINS="broken,classic,rival")
    listed = plugin_dists.i2pbench("plugins", "--json", env=env, cwd=tmp_path, timeout=300)
    assert listed.returncode == 0, listed.stderr
    rows = {r["plugin"]: r for r in json.loads(listed.stdout)}
    assert rows["broken"]["status"] == "failed" and "i2pbench_no_such_module" in rows["broken"]["error"]
    assert rows["rival"]["status"] == "failed" and rows["rival"]["components"] == {}
    assert rows["classic"]["status"] == "ok" and "lsd" in rows["classic"]["components"]["extractor2d"]
    assert listed.stderr.count("i2pbench: warning: plugin") == 2
    text = plugin_dists.i2pbench("plugins", env=env, cwd=tmp_path, timeout=300)
    assert text.returncode == 0
    assert "broken 0.1 (i2pbench-test-plugins) FAILED: failed to import" in text.stdout


def test_other_commands_keep_working_past_a_broken_plugin(site, tmp_path):
    plugin_dists.install(site, {"toy": "toy_plugin"}, name="toy-plugin")
    env = plugin_dists.env(site, I2PBENCH_LOAD_PLUGINS="broken,toy")
    stages = ["--extractor", "grid", "--extractor3d", "first", "--matcher", "truth", "--solver", "truth"]
    done = plugin_dists.i2pbench("run", "--dataset", "toy", *stages, "--quiet", env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "plugin 'broken' failed to import" in done.stderr
    assert "| grid > first > truth > truth |" in done.stdout
