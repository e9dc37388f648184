"""Component configs merge over their defaults at every depth, refuse unknown keys with the closest valid one, and
resolve to the configs (and so the cache keys) the one-level merge plus the plugins' own nested patches gave."""

import pytest
from test_cli_errors import assert_refused, i2pbench

from i2pbench.errors import PluginError
from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import parse_conf_overrides
from i2pbench.runs.jobs import _described
from i2pbench.runs.store import cache_key
from i2pbench.stages.config import ConfigError, merge_conf, overlay

# (kind, name, overrides) -> the cache key of the stage's description, computed before the deep merge existed (the
# two PointNet++ encoders' recomputed when layers.pointnet2 and layers.kernels went to REVISION 1, issue 39)
KEYS = [
    ("extractor2d", "lsd", None, "a5ddd8ab6ed036d039c1b670"),
    ("extractor3d", "depth", None, "48470a80705c9ce928a05704"),
    ("matcher", "oracle", None, "91b609ed9b253d311cbbf2ec"),
    ("solver", "epnp-ransac", {"reprojection_error_px": 4.0}, "c8ef59e52049a0f806f85855"),
    ("encoder3d", "pointnet2", {"sa1": {"radius": 0.2}}, "b4b3bc3d727898e8927cace8"),
    ("encoder3d", "corri2p-pointnet2", {"sa2": {"nsample": 8}, "num_points": 1024}, "ac74c41eb54c98f1871db2fd"),
    ("matcher", "lightglue", {"weights": {"fov": 2.0}}, "4f026e7b05bf0444ec0b58ed"),
]


@pytest.mark.parametrize(("kind", "name", "conf", "key"), KEYS, ids=[f"{k[1]}" for k in KEYS])
def test_resolved_configs_keep_their_cache_keys(kind, name, conf, key):
    component = default_registry().component(kind, name)(conf)
    assert cache_key(_described(component)) == key


DEFAULTS = {"dim": 4, "sa1": {"npoint": 128, "radius": 0.1, "mlp": (32, 64)}, "extra": {}}


def test_a_partial_nested_override_keeps_the_other_nested_defaults():
    conf = merge_conf(DEFAULTS, {"sa1": {"radius": 0.2}}, "encoder3d 'x'")
    assert conf == {"dim": 4, "sa1": {"npoint": 128, "radius": 0.2, "mlp": (32, 64)}, "extra": {}}
    assert DEFAULTS["sa1"]["radius"] == 0.1  # the class's defaults are never changed


def test_a_misspelled_nested_key_names_its_path_and_the_closest_valid_one():
    with pytest.raises(ConfigError) as refused:
        merge_conf(DEFAULTS, {"sa1": {"raduis": 0.2}}, "encoder3d 'x'")
    message = str(refused.value)
    assert "unknown config key 'sa1.raduis'" in message and "did you mean 'sa1.radius'?" in message
    assert message.startswith("encoder3d 'x': ")


def test_a_nested_value_of_another_kind_is_refused_with_its_path():
    with pytest.raises(ConfigError, match="config sa1.npoint = 'many' is a string, but sa1.npoint takes a number"):
        merge_conf(DEFAULTS, {"sa1": {"npoint": "many"}}, "encoder3d 'x'")


def test_an_empty_mapping_default_takes_any_mapping_and_none_replaces_a_mapping():
    assert merge_conf(DEFAULTS, {"extra": {"anything": 1}}, "x")["extra"] == {"anything": 1}
    assert merge_conf(DEFAULTS, {"sa1": None}, "x")["sa1"] is None


def test_overlay_merges_nested_mappings_and_replaces_the_rest():
    assert overlay({"a": {"b": 1, "c": 2}, "d": [1]}, {"a": {"c": 3}, "d": [2]}) == {"a": {"b": 1, "c": 3}, "d": [2]}


def test_dotted_conf_keys_nest_and_several_settings_of_one_mapping_combine():
    confs = parse_conf_overrides(["encoder3d.sa1.radius=0.2", "encoder3d.sa1.npoint=64", "matcher.dim=8"])
    assert confs == {"encoder3d": {"sa1": {"radius": 0.2, "npoint": 64}}, "matcher": {"dim": 8}}
    with pytest.raises(PluginError, match="expected KIND.KEY=VALUE"):
        parse_conf_overrides(["matcher.weights.=1"])


@pytest.mark.parametrize(
    ("option", "named"),
    [
        (["--matcher", "lightglue", "--conf", "matcher.weights.fvo=1"], ["'weights.fvo'", "'weights.fov'"]),
        (["--data-conf", "frames.tset=3"], ["dataset 'synthetic'", "'frames.tset'", "'frames.test'"]),
    ],
    ids=["component", "dataset"],
)
def test_a_misspelled_nested_key_on_the_command_line_is_one_error_line(option, named, tmp_path):
    done = i2pbench("run", *option, "--runs-dir", str(tmp_path / "runs"), "--data-root", str(tmp_path), cwd=tmp_path)
    assert_refused(done, *named)
    assert not (tmp_path / "runs").exists()  # refused before the run's store is made
