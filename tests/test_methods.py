"""A method declared through `register_methods` gets presets, variant labels, `--weights auto` and the checkpoint
check with no other glue; `plugins` lists it with module paths; an alias is the component it names."""

import argparse
import dataclasses
import json
import re
import types

import pytest
import toy_method
import toy_plugin

from i2pbench.api import Method, MethodPreset, Row, Size, hookimpl
from i2pbench.commands import plugins as plugins_command
from i2pbench.errors import PluginError, WeightsError
from i2pbench.registry.build import build_registry
from i2pbench.runs.grid import base_combinations, expand
from i2pbench.runs.jobs import prepare
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.weights.checkpoints import file_digest, load_checkpoint, mismatch, save_checkpoint

REFERENCE_ROW = "grid > first > linear > regress > truth"


@pytest.fixture(autouse=True)
def isolated(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")


def _registry(*weights, strict=True):
    return build_registry((toy_plugin, toy_method.ToyMethodPlugin(tuple(weights))), strict=strict)


def _rows(registry, preset: str = "toy-sizes") -> list[Combination]:
    return expand(base_combinations(registry, preset), {}, None, registry)


def test_a_method_registers_its_presets_attributed_to_it_and_its_plugin():
    registry = _registry()
    assert registry.method("toy").sizes == (toy_method.REFERENCE, toy_method.TINY)
    preset = registry.preset("toy-tiny")
    assert (preset.plugin, preset.method) == ("toy-method", "toy")
    row = {**toy_method.STAGES, "confs": {"encoder2d": {"dim": 2}}, "variant": "tiny"}
    assert preset.combinations == (row,)  # the row register_presets would have been given by hand


def test_rows_carry_their_size_label_and_a_swapped_stage_leaves_its_size_behind():
    rows = _rows(_registry())
    assert [r.display for r in rows] == [REFERENCE_ROW, f"{REFERENCE_ROW} (tiny)", "grid > first > truth > truth"]
    assert [dict(r.confs) for r in rows] == [{"encoder2d": {"dim": 4}}, {"encoder2d": {"dim": 2}}, {}]


def _saved(registry, tmp_path, row: int):
    pipeline = Pipeline.build(registry, _rows(registry)[row])
    return save_checkpoint(tmp_path / f"toy-{row}.pt", pipeline, steps=1, trained_on={"dataset": "toy"})


def test_auto_weights_give_each_row_the_shipped_checkpoint_of_its_size_only(tmp_path):
    tiny = _saved(_registry(), tmp_path, row=1)
    registry = _registry(tiny)
    assert registry.weights.owners() == {str(tiny): "toy-method"}
    jobs = prepare(registry, _rows(registry))
    assert [job.weights for job in jobs] == ["untrained", load_checkpoint(tiny).identity, "none"]


def test_the_checkpoint_check_refuses_a_size_the_weights_were_not_trained_at(tmp_path):
    registry = _registry()
    checkpoint = load_checkpoint(_saved(registry, tmp_path, row=1))
    reference = Pipeline.build(registry, _rows(registry)[0])
    reason = mismatch(checkpoint, reference, strict_extractors=True)
    assert reason == (
        "encoder2d: the pipeline has 'linear' {'dim': 4} but checkpoint toy-1.pt was trained with 'linear' {'dim': 2}"
    )


def test_a_size_may_run_other_components_than_its_method(tmp_path):
    method = Method("m", toy_method.STAGES, (Size("own", {"encoder2d": {"dim": 3}}, stages={"encoder2d": "constant"}),))
    method.check()
    row = method.row("own")
    assert row["encoder2d"] == "constant" and row["confs"] == {"encoder2d": {"dim": 3}}
    assert method.row("own", encoder2d="linear")["confs"] == {}  # a swapped stage leaves the size's confs behind
    with pytest.raises(PluginError, match=r"configures kinds \['exchanger'\]"):
        Method("m", toy_method.STAGES, (Size("bad", stages={"exchanger": "x"}),)).check()


def test_a_methods_importer_writes_a_checkpoint_of_its_size_recording_the_source(tmp_path):
    from i2pbench.weights.checkpoints import import_weights

    source = tmp_path / "release.json"
    source.write_text(json.dumps({"w": [[1.0, 2.0], [3.0, 4.0]], "b": [0.5, -0.5]}))
    checkpoint = load_checkpoint(import_weights(_registry(), "toy-release", source, tmp_path / "W.pt"))
    assert checkpoint.meta["stages"]["encoder2d"] == {"name": "linear", "conf": {"dim": 2}}
    assert checkpoint.trained_on == "a toy release"
    origin = checkpoint.meta["imported_from"]
    assert origin == {
        "file": "release.json",
        "sha256": file_digest(source),
        "importer": "toy-release",
        "format": "json",
    }
    assert checkpoint.state["encoder2d"]["layer.bias"].tolist() == [0.5, -0.5]
    source.write_text(json.dumps({"w": [[1.0, 2.0, 3.0]] * 2, "b": [0.5, -0.5]}))
    with pytest.raises(WeightsError, match="(?s)does not load into encoder2d 'linear'.*size mismatch"):
        import_weights(_registry(), "toy-release", source, tmp_path / "W2.pt")
    with pytest.raises(WeightsError, match=r"unknown weights importer 'toy' \(known: toy-release\)"):
        import_weights(_registry(), "toy", source, tmp_path / "W2.pt")


def _listing(registry, monkeypatch, capsys, *options: str) -> str:
    monkeypatch.setattr("i2pbench.registry.build.default_registry", lambda: registry)
    assert plugins_command.run(argparse.Namespace(json="--json" in options)) == 0
    return capsys.readouterr().out


def test_plugins_lists_the_method_and_each_component_with_its_module(monkeypatch, capsys, tmp_path):
    registry = _registry(tmp_path / "toy-tiny.pt")
    text = _listing(registry, monkeypatch, capsys)
    assert "  encoder2d    constant     toy_plugin:ConstantEncoder\n" in text
    assert "               linear       toy_plugin:LinearEncoder\n" in text
    assert "  method       toy  a linear encoder trained by regression\n" in text
    assert "    stages     grid > first > linear > regress > truth\n" in text
    assert "    size       reference  the encoder's own width; rows unlabelled\n" in text
    assert "    size       tiny       half the width\n" in text
    assert "    presets    toy-tiny, toy-sizes\n    weights    toy-tiny.pt\n" in text
    rows = {row["plugin"]: row for row in json.loads(_listing(registry, monkeypatch, capsys, "--json"))}
    assert rows["toy_plugin"]["modules"]["matcher"]["regress"] == "toy_plugin:RegressionMatcher"
    method = rows["toy-method"]["methods"][0]
    assert method["sizes"]["tiny"] == {"variant": "tiny", "description": "half the width"}
    listed = rows["toy-method"]["components"]
    assert listed == {"preset": ["toy-sizes", "toy-tiny"], "weights": ["toy-tiny.pt"], "method": ["toy"]}


def _aliasing(hook: str, target, name: str, aliases) -> types.ModuleType:
    module = types.ModuleType("aliasing")
    setattr(module, hook, hookimpl(lambda register: register(target, name=name, aliases=aliases)))
    return module


def test_an_alias_is_the_component_it_names_in_rows_keys_and_listings(monkeypatch, capsys):
    plugin = _aliasing("register_matchers", "toy_plugin:RegressionMatcher", "regress", ("mse-matcher",))
    registry = build_registry((toy_plugin, plugin), strict=True)  # the same class again, now with an alias
    assert registry.component("matcher", "mse-matcher") is toy_plugin.RegressionMatcher
    assert registry.canonical("matcher", "mse-matcher") == "regress"
    base = [{**toy_method.STAGES, "encoder2d": "none"}]
    by_alias, by_name = (expand(base, {"matcher": [n]}, None, registry)[0] for n in ("mse-matcher", "regress"))
    assert by_alias.key() == by_name.key() and by_alias.label == by_name.label == "grid > first > regress > truth"
    with pytest.raises(PluginError, match="did you mean 'mse-matcher'"):
        registry.component("matcher", "mse-matchr")
    line = "  matcher      regress  toy_plugin:RegressionMatcher  (alias: mse-matcher)\n"
    assert f"aliasing local (local)\n{line}" in _listing(registry, monkeypatch, capsys)


def test_edgeregnets_matcher_answers_to_its_honest_name_with_the_committed_label(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "classic,edgeregnet")
    registry = build_registry()
    assert registry.component("matcher", "optimal-matching") is registry.component("matcher", "lightglue")
    bases = base_combinations(registry, None)
    honest, old = (expand(bases, {"matcher": [n]}, None, registry)[0] for n in ("optimal-matching", "lightglue"))
    assert honest.display == old.display and honest.key() == old.key()
    assert honest.display.endswith("> attention > lightglue > epnp-ransac (cpu-size)")


def _renamed(*aliases: str) -> Method:
    """the toy method with its tiny preset renamed, the old name kept as an alias."""
    renamed = MethodPreset("toy", toy_method.PRESETS[0].rows, "the toy method at its tiny size", aliases=aliases)
    return dataclasses.replace(toy_method.method(), presets=(renamed, *toy_method.PRESETS[1:]))


def test_a_renamed_preset_answers_to_its_former_name_everywhere_a_preset_is_named(monkeypatch, capsys):
    components = types.ModuleType("components")  # toy_plugin's stages without its presets (it has a "default")
    for hook in [h for h in vars(toy_plugin) if h.startswith("register_") and h != "register_presets"]:
        setattr(components, hook, getattr(toy_plugin, hook))
    including = types.ModuleType("including")
    including.register_presets = hookimpl(lambda register: register("both", ["toy-tiny", "toy-sizes"]))
    renamed = _method_plugin("renamed", _renamed("toy-tiny", "default"))
    registry = build_registry((components, renamed, including), strict=True)
    assert registry.preset("toy-tiny") is registry.preset("toy") and "toy-tiny" not in registry.presets
    assert [r.display for r in _rows(registry, "toy-tiny")] == [f"{REFERENCE_ROW} (tiny)"]
    assert _rows(registry, None) == _rows(registry, "toy")  # "default" as an alias is still the run's default
    assert len(_rows(registry, "both")) == 3  # an included preset named by its alias
    assert "    presets    toy (alias: toy-tiny, default), toy-sizes\n" in _listing(registry, monkeypatch, capsys)


def test_a_preset_alias_taken_by_another_plugin_is_refused():
    error = "preset alias 'default' of 'toy' (plugin 'renamed') is a name of plugin 'toy_plugin'"
    with pytest.raises(PluginError, match=re.escape(error)):
        build_registry((toy_plugin, _method_plugin("renamed", _renamed("default"))), strict=True)


@pytest.mark.parametrize(
    "aliases, error",
    [
        (("truth",), "matcher alias 'truth' of 'regress' (plugin 'aliasing') is a name of plugin 'toy_plugin'"),
        (("regress",), "gave matcher 'regress' the alias 'regress', which is no other name"),
    ],
)
def test_an_alias_that_is_already_a_name_is_refused(aliases, error):
    plugin = _aliasing("register_matchers", "toy_plugin:RegressionMatcher", "regress", aliases)
    with pytest.raises(PluginError, match=re.escape(error)):
        build_registry((toy_plugin, plugin), strict=True)


def test_a_name_that_is_already_an_alias_is_refused():
    first = _aliasing("register_matchers", "toy_plugin:RegressionMatcher", "regress", ("truth",))
    with pytest.raises(PluginError, match="matcher name 'truth' of plugin 'toy_plugin' is an alias registered by"):
        build_registry((first, toy_plugin), strict=True)


def _method_plugin(name: str, *methods: Method):
    module = types.ModuleType(name)

    @hookimpl
    def register_methods(register):
        for method in methods:
            register(method)

    module.register_methods = register_methods
    return module


@pytest.mark.parametrize(
    "method, error",
    [
        (Method("bad", toy_method.STAGES, (toy_method.TINY,), (MethodPreset("p", (Row("huge"),)),)),
         "plugin 'broken': method 'bad' has no size 'huge' \\(sizes: tiny\\)"),
        (Method("bad", toy_method.STAGES, (toy_method.TINY, toy_method.TINY)), "each named once"),
        (Method("bad", toy_method.STAGES, (Size("s", {"exchanger": {}}),)), "configures kinds \\['exchanger'\\]"),
        (Method("bad", {"extractor": "grid"}, (toy_method.TINY,)), "stage kinds among"),
    ],
)  # fmt: skip
def test_a_method_that_cannot_work_is_refused_naming_its_plugin(method, error):
    with pytest.raises(PluginError, match=error):
        build_registry((_method_plugin("broken", method),), strict=True)


def test_a_method_or_preset_name_taken_by_another_plugin_is_refused():
    with pytest.raises(PluginError, match="method 'toy' is registered by both 'toy-method' and 'rival'"):
        build_registry((toy_method.ToyMethodPlugin(), _method_plugin("rival", toy_method.method())), strict=True)
    clash = Method("other", toy_method.STAGES, (toy_method.TINY,), (MethodPreset("default", (Row("tiny"),)),))
    with pytest.raises(PluginError, match="preset 'default' is registered by both 'toy_plugin' and 'rival'"):
        build_registry((toy_plugin, _method_plugin("rival", clash)), strict=True)


def test_a_refused_method_leaves_nothing_behind():
    registry = build_registry((toy_plugin, _method_plugin("rival", toy_method.method(), "not a method")))
    assert "toy" not in registry.methods and "toy-tiny" not in registry.presets
    assert registry.plugins[-1].error.startswith("plugin 'rival' registered 'not a method' as a method")


def test_edgeregnet_is_one_method_from_its_entry_point(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "classic,edgeregnet")
    registry = build_registry()
    method = registry.method("edgeregnet")
    sizes = [s.name for s in method.sizes]
    assert sizes == ["paper", "cpu-size", "official"] and registry.methods.plugin("edgeregnet") == "edgeregnet"
    owned = {name for name, preset in registry.presets.items() if preset.method == "edgeregnet"}
    assert owned == {"edgeregnet", "edgeregnet-paper", "edgeregnet-official", "edge-ablation", "exchange-ablation",
                     "baselines"}  # fmt: skip
    for old, new in (("default", "edgeregnet"), ("edgeregnet-full", "edgeregnet-paper")):  # the former names
        assert registry.presets.canonical(old) == new and registry.preset_rows(old) == registry.preset_rows(new)
    official = registry.preset_rows("edgeregnet-official")[0]
    assert official["encoder2d"] == "superpoint-official" and official["matcher"] == "match-assignment-official"
    assert official["variant"] == "official" and official["confs"]["extractor2d"] == {"max_keypoints": 3000}
    assert list(registry.weights) == [str(w) for w in method.weights] and len(method.weights) == 2


class AblationPlugin:
    """A third party's presets built on the toy method by name, importing nothing of it."""

    __name__ = "ablations"

    @hookimpl
    def register_presets(self, register):
        wider = Row("tiny", method="toy", confs={"encoder2d": {"dim": 3}}, variant="tiny, dim 3")
        truth = Row("tiny", {"matcher": "truth"}, method="toy")
        register("toy-ablation", [Row("reference", method="toy"), wider, Row("tiny", method="absent"), truth])
        register("absent-only", [Row("tiny", method="absent"), Row("paper", method="gone")])


def test_a_preset_row_names_a_registered_method_and_is_built_from_its_declaration():
    registry = build_registry((toy_plugin, AblationPlugin(), toy_method.ToyMethodPlugin()), strict=True)  # any order
    method = registry.method("toy")
    reference, wider, truth = registry.preset_rows("toy-ablation")  # the row of a method nobody registers: left out
    assert reference == method.row("reference") and truth == method.row("tiny", matcher="truth")
    assert wider == {**toy_method.STAGES, "confs": {"encoder2d": {"dim": 3}}, "variant": "tiny, dim 3"}
    assert [c.display for c in expand([reference, wider, truth], {}, None, registry)] == [
        REFERENCE_ROW, f"{REFERENCE_ROW} (tiny, dim 3)", "grid > first > truth > truth"]  # fmt: skip
    with pytest.raises(PluginError, match=r"preset 'absent-only' \(plugin 'ablations'\) is built on method\(s\) "
                                          r"absent, gone, which no loaded plugin registers"):  # fmt: skip
        registry.preset_rows("absent-only")


def test_a_row_in_register_presets_must_name_its_method():
    plugin = types.SimpleNamespace(register_presets=hookimpl(lambda register: register("p", [Row("tiny")])))
    with pytest.raises(PluginError, match=r"preset 'p' has a Row naming no method"):
        build_registry((plugin,), strict=True)


def test_a_method_row_configures_only_stage_kinds():
    with pytest.raises(PluginError, match=r"a row configures unknown stage kinds \['encoder'\]"):
        toy_method.method().resolve(Row("tiny", confs={"encoder": {}}))
