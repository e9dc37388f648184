import numpy as np
import pytest
import toy_plugin

from i2pbench.errors import PluginError
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline

BASE = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin,))


def _run(registry, tmp_path, **stages):
    dataset = registry.dataset("toy")("test")
    return run_grid(registry, [Combination({**BASE, **stages})], dataset, Protocol(), ResultsStore(tmp_path))


def test_end_to_end_with_declared_ground_truth_is_exact(registry, tmp_path):
    records = _run(registry, tmp_path).set_index("frame_id")
    assert records.loc["a", "status"] == "ok"
    assert records.loc["a", "rte_m"] == pytest.approx(0.0, abs=1e-9)
    assert records.loc["a", "rre_deg"] == pytest.approx(0.0, abs=1e-6)
    assert records.loc["a", "n_kp2d"] == 2 and records.loc["a", "n_kp3d"] == 3 and records.loc["a", "n_matches"] == 1


def test_a_bad_frame_is_recorded_as_a_failure_naming_the_file_and_the_run_continues(registry, tmp_path):
    records = _run(registry, tmp_path).set_index("frame_id")
    assert records.loc["bad", "status"] == "failed"
    assert "/data/toy/bad.bin" in records.loc["bad", "error"]
    assert records.loc["bad", "failed_component"] == "dataset 'toy'"
    assert np.isinf(records.loc["bad", "rre_deg"])
    assert records.loc["c", "status"] == "ok"


def test_a_raising_component_gives_a_failed_row_naming_it(registry, tmp_path):
    records = _run(registry, tmp_path, extractor3d="boom").set_index("frame_id")
    row = records.loc["a"]
    assert row["status"] == "failed"
    assert row["failed_component"] == "extractor3d 'boom'"
    assert "RuntimeError: exploded on purpose" in row["error"]
    assert len(records) == 3  # every frame still ran


def test_wrong_shape_is_caught_by_the_contract(registry, tmp_path):
    row = _run(registry, tmp_path, extractor2d="wrong-shape").set_index("frame_id").loc["c"]
    assert row["status"] == "failed"
    assert row["failed_component"] == "extractor2d 'wrong-shape'"
    assert "[M x 2]" in row["error"] and "(5, 3)" in row["error"]


def test_ground_truth_is_hidden_from_stages_that_do_not_declare_it(registry, tmp_path):
    row = _run(registry, tmp_path, matcher="peek").set_index("frame_id").loc["a"]
    assert row["error"] == "" and row["n_matches"] == 0  # peek raised nothing: it saw no T_gt


def test_incompatible_combination_is_refused_before_running_naming_both(registry):
    class NeedsFeatures(toy_plugin.PeekingMatcher):
        name = "needs-features"
        consumes = toy_plugin.PeekingMatcher.consumes | {"features2d"}

    registry.components["matcher"].add("needs-features", NeedsFeatures, "test")
    with pytest.raises(PluginError, match="matcher 'needs-features' needs features2d, but encoder2d 'none'"):
        Pipeline.build(registry, Combination({**BASE, "matcher": "needs-features"}))
    Pipeline.build(registry, Combination({**BASE, "matcher": "needs-features", "encoder2d": "constant"}))


def test_missing_required_stage_is_refused(registry):
    with pytest.raises(PluginError, match="has no solver"):
        Pipeline.build(registry, Combination({k: v for k, v in BASE.items() if k != "solver"}))


def test_timings_cover_each_stage_that_ran(registry, tmp_path):
    row = _run(registry, tmp_path).set_index("frame_id").loc["a"]
    for kind in ("extractor2d", "extractor3d", "matcher", "solver"):
        assert row[f"t_{kind}_s"] >= 0
    assert np.isnan(row["t_encoder2d_s"])
    assert row["t_total_s"] == pytest.approx(
        sum(row[f"t_{k}_s"] for k in ("extractor2d", "extractor3d", "matcher", "solver"))
    )
