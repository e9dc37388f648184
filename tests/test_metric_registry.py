"""A metric declared once, in a plugin, reaches every reader: the store's records, the run's leaderboard, `evaluate`
and training validation; and the registry refuses a metric it could not aggregate."""

import pickle

import pandas as pd
import pytest
import torch
import toy_plugin
from test_weights_and_training import LEARNED, Clean

from i2pbench.api import Metric, hookimpl
from i2pbench.boards import leaderboard, uncertainty
from i2pbench.boards.regression_gate import compare, parse_tolerances
from i2pbench.cli import main
from i2pbench.errors import I2PBenchError, PluginError
from i2pbench.registry import build
from i2pbench.registry.build import build_registry
from i2pbench.registry.listing import components_of
from i2pbench.runs.executors import run_grid
from i2pbench.runs.jobs import frame_key, prepare, upstream_key
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.installed import by_name
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.training.config import TrainConfig
from i2pbench.training.loop import Trainer

COLUMN = "keypoints per match ↓"
TRUTH = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


def keypoints_per_match(scored):
    """image keypoints over matches: the toy grid gives 2 keypoints, the truth matcher 1 match (2.0)."""
    return scored.outcome.n_kp2d / max(scored.outcome.n_matches, 1)


class MetricPlugin:
    __name__ = "metric-plugin"

    @hookimpl
    def register_metrics(self, register):
        register(Metric("kp_per_match", COLUMN, False, frame=keypoints_per_match, aggregate="mean", scale=10.0))


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    built = build_registry((toy_plugin, MetricPlugin()))
    monkeypatch.setattr(build, "default_registry", lambda: built)  # what `run`, `evaluate` and training read
    return built


def test_a_plugin_metric_reaches_the_store_the_board_evaluate_and_validation(registry, tmp_path):
    assert components_of(registry, "metric-plugin") == {"metric": ["kp_per_match"]}
    runs = tmp_path / "runs"
    argv = ["run", "--dataset", "toy", "--extractor", "grid", "--extractor3d", "first", "--matcher", "truth",
            "--solver", "truth", "--runs-dir", str(runs), "--out", str(tmp_path / "board"), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    records = ResultsStore(runs / "toy-test").load().set_index("frame_id")
    assert records.loc["a", "kp_per_match"] == records.loc["c", "kp_per_match"] == 2.0  # 2 keypoints, 1 match
    assert records.loc["bad", "kp_per_match"] == 0.0  # failed to load: no keypoint, no match (0 / max(0, 1))
    board = leaderboard.read(tmp_path / "board.csv")
    assert board[COLUMN].tolist() == [pytest.approx(10 * (2.0 + 0.0 + 2.0) / 3)]  # mean over 3 frames, times 10
    assert main(["evaluate", str(runs / "toy-test"), "--out", str(tmp_path / "again")]) == 0
    assert leaderboard.read(tmp_path / "again.csv")[COLUMN].tolist() == board[COLUMN].tolist()
    assert f"| {COLUMN} | {uncertainty.ci(by_name()['kp_per_match'])} |" in (tmp_path / "board.md").read_text()
    worse = board.assign(**{COLUMN: board[COLUMN] + 1.0})  # lower is better: one more keypoint per match, times 10
    report = compare(worse, board, parse_tolerances("kp_per_match=+0.5"))  # compare checks it under its name
    assert [(f.what, f.base, f.new) for f in report.findings] == [("kp_per_match", board[COLUMN][0], worse[COLUMN][0])]

    torch.manual_seed(0)
    pipeline = Pipeline.build(registry, Combination(LEARNED))
    trainer = Trainer(pipeline, Clean("test"), Clean("test"), tmp_path / "w.pt", TrainConfig(steps=1, val_frames=2))
    validation = trainer.validate()
    assert validation["frames"] == 2 and validation["kp_per_match"] == 20.0  # frames a and c: 2.0 each, times 10
    assert {"acc_pct", "skill_acc_pct", "chance", "true_matches_median"} <= set(validation)


@pytest.mark.parametrize(
    ("metric", "says"),
    [
        ("not a metric", "is no i2pbench.api.Metric"),
        (Metric("x", "x ↑", True, frame=len, aggregate="mode"), "an aggregate in"),
        (Metric("x", "x ↑", frame=len), "no higher_is_better"),
        (Metric("x", "x ↑", True), "needs `frame`"),
        (Metric("acc_pct", "mine ↑", True, frame=len), "'acc_pct' is registered by both 'i2pbench' and 'bad'"),
        (Metric("mine", leaderboard.ACC, True, frame=len), "registered by both 'i2pbench' and 'bad'"),
    ],
)
def test_a_metric_that_cannot_be_aggregated_or_clashes_is_refused_naming_the_plugin(monkeypatch, metric, says):
    class Bad:
        __name__ = "bad"

        @hookimpl
        def register_metrics(self, register):
            register(metric)

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    with pytest.raises(PluginError, match=says):
        build_registry((Bad(),), strict=True)


def test_the_board_keeps_its_columns_order_and_appends_a_new_metric(registry):
    records = pd.DataFrame({
        "dataset": "toy", "split": "test", "combination": "c", "weights": "none", "extractor2d": "grid",
        "extractor3d": "first", "encoder2d": "none", "encoder3d": "none", "exchanger": "none", "matcher": "truth",
        "solver": "truth", "status": ["ok", "ok"], "failed_component": "", "rte_m": [0.5, 3.0],
        "rre_deg": [1.0, 2.0], "geodesic_deg": [1.0, 2.0], "n_matches": [10, 10], "n_true_matches": [8.0, 2.0],
        "model_size_mb": 0.0, "t_total_s": [0.1, 0.1], "kp_per_match": [2.0, 4.0],
    })  # fmt: skip
    board = leaderboard.build(records)
    columns = list(board.columns)
    legacy = [leaderboard.ACC, leaderboard.RTE, leaderboard.RRE, "rte_mean", "rte_std", "rre_mean", "rre_std"]
    assert columns[columns.index("kept") + 1 : columns.index("kept") + 8] == legacy
    assert columns.index(COLUMN) > columns.index(leaderboard.LATENCY_MEDIAN)  # new columns follow the old ones
    row = board.iloc[0]
    assert row[leaderboard.ACC] == 50.0 and row[leaderboard.CHANCE] == 0  # 0.5 m < 2 m; 3 m is not
    assert row[leaderboard.RTE] == "1.75 ± 1.25"  # both inside 10 m / 10°: mean (0.5+3)/2, population std 1.25
    assert row[leaderboard.INLIER_RATIO] == 50.0  # (8/10 + 2/10) / 2
    assert row[COLUMN] == 30.0  # (2 + 4) / 2 times 10


def test_a_frame_keeps_the_cache_keys_it_had_before_metrics_were_registered(monkeypatch):
    """metrics are computed from a frame's outputs, never part of what is computed: a frame's keys (dataset, stage
    configs, weights, the default protocol card) are the ones computed at 47c4773, before the registry existed."""
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    stages = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
    (job,) = prepare(registry, [Combination(stages)])
    dataset = registry.dataset("toy")("test")
    assert frame_key(dataset, "a", job, Protocol()) == "b015e1602e1691ae355088c9-1c4d24f82c65"
    assert upstream_key(dataset, "a", job, Protocol()) == "402cc086ad0fe077c2ecc145-1c4d24f82c65"


def test_the_run_s_registry_scores_its_frames_and_names_its_board_not_the_installed_one(tmp_path, monkeypatch):
    """run_grid hands its registry's metrics down to the workers and the board: nothing reads the global registry,
    so a registry with one more plugin metric scores with it while the installed registry knows no such metric."""
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    own = build_registry((toy_plugin, MetricPlugin()))
    assert "kp_per_match" not in by_name()  # the installed registry (no plugin selected) has no such metric
    dataset = own.datasets["toy"]("test", {})
    records = pd.DataFrame(
        run_grid(own, [Combination(TRUTH)], dataset, Protocol(), ResultsStore(tmp_path), frame_ids=["a", "c"])
    )
    assert records["kp_per_match"].tolist() == [2.0, 2.0]  # 2 keypoints, 1 match, per frame
    board = leaderboard.build(records, Protocol(), registry=own)
    assert board[COLUMN].tolist() == [20.0]  # mean 2.0, times 10
    assert COLUMN not in leaderboard.build(records, Protocol())  # the installed registry's board lacks it


def test_metrics_cross_to_workers_by_name_and_one_unknown_there_is_refused_by_name():
    """a metric's callables are lambdas: it pickles as its name, found again among the worker's installed ones."""
    builtin = by_name()["acc_pct"]
    assert pickle.loads(pickle.dumps(builtin)) is builtin
    alien = Metric("alien_metric", "alien ↑", True, frame=lambda scored: 1.0)
    with pytest.raises(I2PBenchError, match="metric 'alien_metric' is not installed in this process"):
        pickle.loads(pickle.dumps(alien))
