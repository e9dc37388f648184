"""Combinations: per-stage lists run as their product, YAML grid files, and the paper's ablation presets."""

import argparse

import pytest
import toy_plugin

from i2pbench.commands.options import chosen_combinations, parse_data_conf
from i2pbench.errors import PluginError
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.runs.grid import base_combinations, expand, load_grid_file
from i2pbench.runs.jobs import prepare

CLASSIC = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}
LEARNED = ("superpoint-cnn", "pointnet2", "lightglue", "epnp-ransac")


def _names(combinations, *kinds):
    return [tuple(c.name(k) for k in kinds) for c in combinations]


def _args(**options):
    """The namespace `i2pbench run` parses, with no stage named unless given."""
    stages = ("extractor2d", "extractor3d", "encoder2d", "encoder3d", "exchanger", "matcher", "solver")
    return argparse.Namespace(**{**dict.fromkeys(stages), "preset": None, "grid": None, "conf": [], **options})


def test_lists_run_as_their_product_in_order():
    combos = expand([CLASSIC], {"extractor2d": ["lsd", "canny"], "solver": ["epnp-ransac", "poselib", "epnp-ransac"]})
    assert _names(combos, "extractor2d", "solver") == [
        ("lsd", "epnp-ransac"),
        ("lsd", "poselib"),
        ("canny", "epnp-ransac"),
        ("canny", "poselib"),
    ]  # the repeated solver is dropped
    assert {c.name("matcher") for c in combos} == {"oracle"}


def test_a_grid_file_gives_base_product_and_confs(tmp_path):
    path = tmp_path / "grid.yaml"
    path.write_text(
        "base: {extractor3d: depth+reflectance, matcher: oracle, exchanger: null}\n"
        "grid:\n  extractor2d: [lsd, canny, sobel]\n  solver: [epnp-ransac, poselib]\n"
        "confs: {solver: {seed: 3}}\n"
    )
    grid = load_grid_file(path)
    assert grid.base == {"extractor3d": "depth+reflectance", "matcher": "oracle", "exchanger": "none"}
    combos = expand([grid.base], grid.grid, grid.confs)
    assert len(combos) == 6
    assert all(c.confs == {"solver": {"seed": 3}} for c in combos)


@pytest.mark.parametrize(
    "text, message",
    [("grid: {extractor: [lsd]}\n", "unknown stage kinds \\['extractor'\\]"), ("stages: {}\n", "expected a mapping")],
)
def test_a_wrong_grid_file_is_refused_naming_it(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(PluginError, match=f"bad.yaml.*{message}"):
        load_grid_file(path)


def test_the_cli_merges_grid_file_and_options_with_options_winning(tmp_path, monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    path = tmp_path / "grid.yaml"
    path.write_text(
        "base: {extractor3d: first, matcher: truth, solver: truth}\ngrid: {extractor2d: [grid, wrong-shape]}\n"
    )
    assert len(chosen_combinations(registry, _args(grid=str(path)))) == 2
    chosen = chosen_combinations(registry, _args(grid=str(path), extractor2d=["grid"]))
    assert _names(chosen, "extractor2d") == [("grid",)]


def test_named_stages_need_no_default_preset(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry(())
    assert base_combinations(registry, None, stages_named=True) == [{}]
    with pytest.raises(PluginError, match="no 'default' preset"):
        base_combinations(registry, None)


def test_comma_separated_presets_run_their_union_once_each():
    registry = default_registry()
    baselines = base_combinations(registry, "baselines")
    exchange = base_combinations(registry, "exchange-ablation")
    union = base_combinations(registry, "baselines, exchange-ablation")
    assert len(exchange) == 2 and all(c in baselines for c in exchange)  # both exchange rows are baselines rows
    assert union == baselines  # so the union adds nothing and keeps the order
    both = base_combinations(registry, "exchange-ablation,edge-ablation")
    assert both[:2] == exchange and len(both) == 2 + 6 - 1  # edge-ablation's lsd x d+r row is exchange's attention


def test_data_conf_nests_dotted_keys():
    assert parse_data_conf(["frames.test=3", "seed=1", "root=/x"]) == {"frames": {"test": 3}, "seed": 1, "root": "/x"}


def test_edge_ablation_is_table_iii_with_the_learned_stages_in_every_row():
    registry = default_registry()
    combos = expand(registry.preset("edge-ablation").combinations, {})
    assert _names(combos, "extractor3d", "extractor2d") == [
        ("random", "random"),
        ("depth+reflectance", "canny"),
        ("depth+reflectance", "sobel"),
        ("reflectance", "lsd"),
        ("depth", "lsd"),
        ("depth+reflectance", "lsd"),
    ]
    assert set(_names(combos, "encoder2d", "encoder3d", "matcher", "solver")) == {LEARNED}
    assert {c.name("exchanger") for c in combos} == {"attention"}
    jobs = prepare(registry, combos)  # every row is a valid pipeline
    assert all(job.weights == "untrained" or "@" in job.weights for job in jobs)


def test_exchange_ablation_is_table_iv():
    registry = default_registry()
    combos = expand(registry.preset("exchange-ablation").combinations, {})
    assert _names(combos, "extractor2d", "extractor3d", "exchanger") == [
        ("lsd", "depth+reflectance", "none"),
        ("lsd", "depth+reflectance", "attention"),
    ]
    assert set(_names(combos, "encoder2d", "encoder3d", "matcher", "solver")) == {LEARNED}
    prepare(registry, combos)


def test_stages_from_the_base_that_nothing_consumes_are_dropped_but_named_ones_kept():
    from i2pbench.registry.build import default_registry
    from i2pbench.runs.grid import expand

    registry = default_registry()
    bases = base_combinations(registry, None)
    oracle = expand(bases, {"matcher": ["oracle"]}, registry=registry)[0]
    assert oracle.label == "lsd > depth+reflectance > oracle > epnp-ransac"
    assert "matcher" not in oracle.confs  # lightglue's pinned width does not leak onto the oracle
    named = expand(bases, {"matcher": ["oracle"], "encoder2d": ["superpoint-cnn"]}, registry=registry)[0]
    assert named.name("encoder2d") == "superpoint-cnn" and named.name("encoder3d") == "none"
    cosine = expand(bases, {"matcher": ["cosine"]}, registry=registry)[0]
    assert cosine.name("exchanger") == "attention" and cosine.name("encoder3d") == "pointnet2"


def test_extractor_caps_pinned_for_the_learned_stages_leave_with_them():
    from i2pbench.registry.build import default_registry
    from i2pbench.runs.grid import expand

    registry = default_registry()
    bases = base_combinations(registry, None)
    learned = expand(bases, {"extractor2d": ["canny"]}, registry=registry)[0]
    assert learned.confs["extractor3d"]["max_keypoints"] == 2048  # still serving the CPU-sized network
    assert "extractor2d" not in learned.confs  # canny is not the base's lsd: its own defaults
    classic = expand(bases, {"matcher": ["oracle"]}, registry=registry)[0]
    assert classic.confs == {} and classic.variant == ""
