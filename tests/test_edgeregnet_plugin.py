"""The edgeregnet plugin registers its components, and refuses descriptor sizes that disagree."""

import pytest
from i2pbench_edgeregnet import configs
from i2pbench_edgeregnet.attention import AttentionExchanger
from i2pbench_edgeregnet.matching import OptimalMatcher
from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder
from i2pbench_edgeregnet.superpoint import SuperPointEncoder

from i2pbench.registry.build import build_registry


def test_components_are_registered(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "edgeregnet")
    registry = build_registry()
    assert registry.component("encoder2d", "superpoint-cnn") is SuperPointEncoder
    assert registry.component("encoder3d", "pointnet2") is PointNet2Encoder
    assert registry.component("exchanger", "attention") is AttentionExchanger
    assert registry.component("matcher", "lightglue") is OptimalMatcher
    assert registry.owner("matcher", "lightglue") == "edgeregnet"


SMALL = {"descriptor_dim": 64}


def test_matching_sizes_are_accepted():
    upstream = {"encoder2d": SuperPointEncoder(SMALL), "encoder3d": PointNet2Encoder(SMALL)}
    upstream["exchanger"] = AttentionExchanger({**SMALL, "num_blocks": 1})
    assert OptimalMatcher(SMALL).check_compatible(upstream) is None


@pytest.mark.parametrize("kind", ["encoder2d", "encoder3d"])
def test_a_matcher_refuses_an_encoder_of_another_size(kind):
    other = {"encoder2d": SuperPointEncoder, "encoder3d": PointNet2Encoder}[kind](SMALL)
    reason = OptimalMatcher().check_compatible({kind: other})
    assert reason == f"matcher 'lightglue' has descriptor_dim 256 but {kind} {other.name!r} has descriptor_dim 64"


def test_an_exchanger_refuses_an_encoder_of_another_size():
    reason = AttentionExchanger({**SMALL, "num_blocks": 1}).check_compatible({"encoder2d": SuperPointEncoder()})
    assert "exchanger 'attention' has descriptor_dim 64" in reason and "encoder2d 'superpoint-cnn'" in reason


@pytest.mark.parametrize("variant", ["PAPER", "CPU"])
def test_shipped_configs_build_and_agree(variant):
    conf = getattr(configs, variant)
    classes = {"encoder2d": SuperPointEncoder, "encoder3d": PointNet2Encoder, "exchanger": AttentionExchanger}
    upstream = {kind: cls(conf[kind]) for kind, cls in classes.items()}
    assert OptimalMatcher(conf["matcher"]).check_compatible(upstream) is None
    assert {kind: cls.name for kind, cls in classes.items()} | {"matcher": "lightglue"} == configs.COMPONENTS


def _matcher_pipeline(**matcher_conf):
    from i2pbench.stages.pipeline import Combination, Pipeline

    stages = {"extractor2d": "random", "extractor3d": "random", **configs.COMPONENTS, "exchanger": "none"}
    confs = {"encoder2d": SMALL, "encoder3d": SMALL, "matcher": {**SMALL, **matcher_conf}}
    combination = Combination({**stages, "solver": "epnp-ransac"}, confs)
    return Pipeline.build(build_registry(), combination)


def test_inference_thresholds_do_not_change_which_checkpoint_fits(tmp_path):
    from i2pbench.errors import WeightsError
    from i2pbench.weights.checkpoints import apply_checkpoint, load_checkpoint, save_checkpoint

    checkpoint = load_checkpoint(save_checkpoint(tmp_path / "m.pt", _matcher_pipeline(), steps=1))
    swept = _matcher_pipeline(filter_threshold=0.2, fov_filter=False)
    apply_checkpoint(swept, checkpoint)  # runtime keys: accepted
    assert swept.weights_identity == checkpoint.identity
    assert checkpoint.meta["stages"]["matcher"]["conf"]["filter_threshold"] == 0.0  # stored for the record
    with pytest.raises(WeightsError, match="eps_c"):  # a loss setting is part of how the weights were made
        apply_checkpoint(_matcher_pipeline(eps_c=5.0), checkpoint)


def test_the_shipped_checkpoints_fit_the_presets_that_use_them():
    """Configs and committed weights move together: the default row and the no-exchange row get their checkpoints."""
    from i2pbench.runs.grid import base_combinations, expand
    from i2pbench.runs.jobs import prepare

    registry = build_registry()
    rows = expand(base_combinations(registry, "baselines"), {}, None, registry)
    weights = {job.combination.name("exchanger"): job.weights for job in prepare(registry, rows)[:2]}
    assert weights["attention"].startswith("edgeregnet-cpu-synthetic@")
    assert weights["none"].startswith("edgeregnet-cpu-noexchange-synthetic@")
