"""Every hook in hookspecs, implemented by one plugin, lands in the registry attributed to that plugin."""

import pytest
import toy_plugin

from i2pbench.api import Corruption, Encoder3D, Exchanger, Method, Metric, Size, hookimpl
from i2pbench.errors import PluginError
from i2pbench.registry.build import build_registry
from i2pbench.registry.hookspecs import HOOK_NAMES
from i2pbench.registry.listing import components_of
from i2pbench.scoring.cards import NATIVE, ProtocolCard
from i2pbench.scoring.rules import ScoringRules
from i2pbench.stages.components import STAGES


class Encoder3DStub(Encoder3D):
    name = "stub3d"


class ExchangerStub(Exchanger):
    name = "stub-exchanger"


class CorruptionStub(Corruption):
    name, kind, levels = "stub-corruption", "image", (1, 2, 3)


class EveryHook:
    """Implements every hook, reusing the toy plugin's classes where it has one."""

    __name__ = "every-hook"

    @hookimpl
    def register_datasets(self, register):
        register(toy_plugin.ToyDataset)

    @hookimpl
    def register_extractors_2d(self, register):
        register(toy_plugin.GridPixels)

    @hookimpl
    def register_extractors_3d(self, register):
        register(toy_plugin.FirstPoints)

    @hookimpl
    def register_encoders_2d(self, register):
        register(toy_plugin.ConstantEncoder)

    @hookimpl
    def register_encoders_3d(self, register):
        register(Encoder3DStub)

    @hookimpl
    def register_exchangers(self, register):
        register(ExchangerStub)

    @hookimpl
    def register_matchers(self, register):
        register(toy_plugin.TruthMatcher)

    @hookimpl
    def register_pose_solvers(self, register):
        register(toy_plugin.GroundTruthSolver)

    @hookimpl
    def register_presets(self, register):
        register("everything", [{"extractor2d": "grid", "solver": "truth"}], "one of each")

    @hookimpl
    def register_methods(self, register):
        stages = {"extractor2d": "grid", "solver": "truth"}
        register(Method("stub-method", stages, (Size("one"),), weights=("/weights/every-hook.pt",)))

    @hookimpl
    def register_corruptions(self, register):
        register(CorruptionStub)

    @hookimpl
    def register_metrics(self, register):
        register(Metric("stub_metric", "stub metric ↑", True, frame=lambda scored: 1.0))

    @hookimpl
    def register_protocols(self, register):
        register(ProtocolCard("stub-protocol", 1, "stub", NATIVE, None, ScoringRules(rre="geodesic"), ("stub",)))


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((EveryHook(),))


def test_the_plugin_implements_every_hook():
    assert set(HOOK_NAMES) == {name for name in dir(EveryHook) if name.startswith("register_")}


def test_each_stage_hook_registers_its_kind(registry):
    expected = {
        "extractor2d": "grid",
        "extractor3d": "first",
        "encoder2d": "constant",
        "encoder3d": "stub3d",
        "exchanger": "stub-exchanger",
        "matcher": "truth",
        "solver": "truth",
    }
    assert set(expected) == set(STAGES)
    for kind, name in expected.items():
        assert registry.owner(kind, name) == "every-hook"


def test_datasets_presets_weights_and_corruptions_are_registered(registry):
    assert registry.dataset("toy") is toy_plugin.ToyDataset
    assert registry.preset("everything").combinations == ({"extractor2d": "grid", "solver": "truth"},)
    assert registry.weights.owners() == {"/weights/every-hook.pt": "every-hook"}
    assert registry.corruption("stub-corruption") is CorruptionStub
    listed = components_of(registry, "every-hook")
    assert (
        listed["dataset"] == ["toy"] and listed["preset"] == ["everything"] and listed["weights"] == ["every-hook.pt"]
    )
    assert listed["corruption"] == ["stub-corruption"]
    assert registry.method("stub-method").sizes == (Size("one"),) and listed["method"] == ["stub-method"]
    assert registry.metrics["stub_metric"].column == "stub metric ↑" and listed["metric"] == ["stub_metric"]
    assert registry.protocols["stub-protocol"].rules.rre == "geodesic" and listed["protocol"] == ["stub-protocol"]


def test_a_class_of_the_wrong_kind_is_refused_naming_the_plugin(monkeypatch):
    class Confused:
        __name__ = "confused"

        @hookimpl
        def register_exchangers(self, register):
            register(toy_plugin.GridPixels)

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    with pytest.raises(PluginError, match="plugin 'confused' registered .* as a exchanger, but it does not subclass"):
        build_registry((Confused(),), strict=True)  # not strict: skipped with a warning (test_plugin_load_failures)
