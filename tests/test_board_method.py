"""Every board row names its method (issue 31, first contact 10): the declared method whose encoder, exchanger or
matcher the row runs (ablations included), else the plugin of its matcher ("classic")."""

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.registry.build import default_registry
from i2pbench.registry.methods import Method, Size, method_of
from i2pbench.stages.components import STAGE_ORDER


@pytest.mark.parametrize(
    ("preset", "method"),
    [
        ("classic-oracle", "classic"),
        ("default", "EdgeRegNet"),
        ("exchange-ablation", "EdgeRegNet"),  # rows without the exchanger are still EdgeRegNet's
        ("corri2p-ablation", "CorrI2P"),  # its third row, ground-truth matches between its extractors, is classic
        ("deepi2p-frustum-2d", "DeepI2P"),
        ("deepi2p-frustum-3d", "DeepI2P"),
    ],
)
def test_every_row_of_a_methods_preset_names_the_method(preset, method):
    registry = default_registry()
    methods, owner = dict(registry.methods), registry.components["matcher"].owners()
    rows = registry.preset_rows(preset)
    full = [{kind: row.get(kind, "none") for kind in STAGE_ORDER} for row in rows]
    named = [method_of(methods, owner, row) for row in full]
    assert named == [method if row["matcher"] != "oracle" else "classic" for row in full]
    assert method in named


def test_a_methods_own_components_decide_before_the_matchers_plugin():
    stages = {"encoder2d": "enc-a", "matcher": "shared"}
    mine = Method("mine", stages, (Size("one", stages={"encoder3d": "enc-b"}),), title="Mine")
    owner = {"shared": "some-plugin", "oracle": "classic"}
    assert method_of({"mine": mine}, owner, {"encoder3d": "enc-b", "matcher": "oracle"}) == "Mine"  # a size's stage
    assert method_of({"mine": mine}, owner, {"encoder2d": "other", "matcher": "oracle"}) == "classic"
    assert method_of({"mine": mine}, owner, {"matcher": "unknown"}) == ""
    assert Method("plain", stages, (Size("one"),)).label == "plain"  # no title: its name


def test_the_board_carries_a_method_column_after_the_old_columns():
    records = pd.DataFrame({
        "dataset": "synthetic", "split": "test", "combination": "lsd > depth > oracle > poselib", "weights": "none",
        **{kind: "none" for kind in STAGE_ORDER}, "extractor2d": "lsd", "extractor3d": "depth", "matcher": "oracle",
        "solver": "poselib", "status": "ok", "failed_component": "", "rte_m": [0.1], "rre_deg": [0.5],
        "geodesic_deg": [0.4], "n_matches": [10], "n_true_matches": [10.0], "model_size_mb": 0.0, "t_total_s": [0.1],
    })  # fmt: skip
    board = leaderboard.build(records)
    assert board["method"].tolist() == ["classic"]
    assert list(board.columns).index("method") > list(board.columns).index(leaderboard.LATENCY_MEDIAN)
    assert "| combination | method |" in leaderboard.to_markdown(board)
