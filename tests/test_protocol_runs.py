"""`run --protocol` and `evaluate --rules` on three real KITTI frames (canny > depth > oracle > epnp-ransac)."""

from __future__ import annotations

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.registry import build
from i2pbench.registry.hookspecs import hookimpl
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring import installed
from i2pbench.scoring.cards import NATIVE, ProtocolCard
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.rules import ScoringRules
from i2pbench.scoring.score import score
from i2pbench.scoring.table import NEEDS_RERUN

STAGES = ["--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]
# success only below 1° and 0.01 m (the oracle's poses are 0.04-0.05 m off: no frame passes), RRE the geodesic angle
STRICT = ProtocolCard("strict-demo", 3, "a demo", NATIVE, NATIVE, ScoringRules(rre="geodesic", acc_rre_deg=1.0,
                      acc_rte_m=0.01, filter_rre_deg=1.0, filter_rte_m=1.0), ("demo",))  # fmt: skip


class Strict:
    @hookimpl
    def register_protocols(self, register):
        register(STRICT)


@pytest.fixture
def strict_installed(monkeypatch):
    registry = build.build_registry(extra_plugins=(Strict(),))
    monkeypatch.setattr(build, "default_registry", lambda: registry)


def run(shared_data, runs, *extra: str) -> int:
    data = ["--dataset", "kitti", "--split", "all", "--data-root", str(shared_data / "kitti_odometry")]
    return main(["run", *STAGES, *data, "--frames", "3", "--runs-dir", str(runs), "--quiet", *extra])


def test_a_card_whose_inputs_i2pbench_cannot_give_is_refused_naming_each(shared_data, tmp_path, capsys):
    assert run(shared_data, tmp_path / "runs", "--protocol", "deepi2p") == 2
    message = capsys.readouterr().err
    assert "protocol deepi2p v1 (DeepI2P) needs inputs i2pbench cannot give its stages on kitti" in message
    assert "sweeps: 3 sweeps accumulated (i2pbench: the frame's sweep)" in message
    assert "frame: another frame's image, up to 10 m away" in message and "nothing was run" in message
    assert not (tmp_path / "runs").exists()


def test_a_run_under_corri2p_is_scored_by_every_card_sharing_its_inputs(shared_data, tmp_path, capsys):
    runs = tmp_path / "runs"
    assert run(shared_data, runs, "--protocol", "corri2p") == 0
    records = ResultsStore(runs / "kitti-all").load()
    assert set(records["protocol"]) == {installed.find("corri2p").protocol(0, "kitti").identity()}
    board = leaderboard.read(runs / "leaderboards" / "kitti-all-canny-depth-oracle-epnp-ransac-corri2p.csv")
    assert board["protocol"].tolist() == ["corri2p v2"] and board[leaderboard.ACC].tolist() == [100.0]  # oracle
    assert main(["evaluate", str(runs / "kitti-all"), "--out", str(tmp_path / "again")]) == 0  # the card's rules
    again = leaderboard.read(tmp_path / "again.csv")
    for column in (leaderboard.ACC, leaderboard.RTE, leaderboard.RRE, "protocol", "recall RRE<1° (%)", "RRE p90 (°)"):
        assert again[column].tolist() == board[column].tolist(), column
    capsys.readouterr()
    assert main(["evaluate", str(runs / "kitti-all"), "--rules", "all", "--out", str(tmp_path / "rules")]) == 0
    err = capsys.readouterr().err
    table = pd.read_csv(tmp_path / "rules.csv")
    for name in ("corri2p", "vp2p-match", "icl"):  # 160 x 512, 40960 points, camera-frame poses: this run's inputs
        expected = score(records, installed.find(name).rules)
        assert table[f"{name} Acc. (%)"].iloc[0] == round(expected["acc_pct"], 2) == 100.0
    for name in ("edgeregnet", "deepi2p", "cofii2p"):
        assert table[name].tolist() == [NEEDS_RERUN]
    assert "cofii2p: needs a rerun (points: 20480 sampled (this run: 40960 sampled))" in err


def test_a_run_under_another_card_is_keyed_labelled_and_scored_by_it(shared_data, tmp_path, strict_installed):
    runs = tmp_path / "runs"
    assert run(shared_data, runs) == 0
    assert run(shared_data, runs, "--protocol", "strict-demo") == 0
    records = ResultsStore(runs / "kitti-all").load()
    strict = STRICT.protocol()
    assert set(records["protocol"]) == {Protocol().identity(), strict.identity()}  # 3 frames computed under each
    assert (records["protocol"] == strict.identity()).sum() == 3
    boards = runs / "leaderboards"
    default = leaderboard.read(boards / "kitti-all-canny-depth-oracle-epnp-ransac.csv")
    board = leaderboard.read(boards / "kitti-all-canny-depth-oracle-epnp-ransac-strict-demo.csv")
    assert default["protocol"].tolist() == ["edgeregnet v1"] and board["protocol"].tolist() == ["strict-demo v3"]
    mine = records[records["protocol"] == strict.identity()]
    expected = score(mine, STRICT.rules)
    assert board[leaderboard.ACC].iloc[0] == round(expected["acc_pct"], 2) == 0.0
    assert default[leaderboard.ACC].iloc[0] == 100.0
    assert board[leaderboard.RRE_MEAN].iloc[0] == pytest.approx(mine["geodesic_deg"].mean(), abs=1e-12)
    assert board[leaderboard.RRE_MEAN].iloc[0] != pytest.approx(mine["rre_deg"].mean(), abs=1e-6)


def test_evaluate_rules_all_scores_the_runs_card_and_lists_the_others_as_needing_a_rerun(shared_data, tmp_path,
                                                                                         capsys):  # fmt: skip
    runs = tmp_path / "runs"
    assert run(shared_data, runs) == 0
    capsys.readouterr()
    assert main(["evaluate", str(runs / "kitti-all"), "--rules", "all", "--out", str(tmp_path / "rules")]) == 0
    out, err = capsys.readouterr()
    table = pd.read_csv(tmp_path / "rules.csv")
    board = leaderboard.read(runs / "leaderboards" / "kitti-all-canny-depth-oracle-epnp-ransac.csv")
    assert table["edgeregnet Acc. (%)"].tolist() == board[leaderboard.ACC].tolist()
    assert table["edgeregnet RTE (m)"].tolist() == board[leaderboard.RTE].tolist()
    assert table["edgeregnet RRE (°)"].tolist() == board[leaderboard.RRE].tolist()
    for name in ("corri2p", "deepi2p", "vp2p-match", "cofii2p", "icl"):
        assert table[name].tolist() == [NEEDS_RERUN], name
        assert f"{name}: needs a rerun (image: " in err and "resized x0.5" in err
    assert out.startswith("| combination | weights | frames | edgeregnet Acc. (%) |")


def test_evaluate_rules_only_scores_every_card_by_its_rules(shared_data, tmp_path):
    runs = tmp_path / "runs"
    assert run(shared_data, runs) == 0
    assert main(["evaluate", str(runs / "kitti-all"), "--rules", "cofii2p,icl", "--rules-only", "--out",
                 str(tmp_path / "rules")]) == 0  # fmt: skip
    table = pd.read_csv(tmp_path / "rules.csv")
    records = ResultsStore(runs / "kitti-all").load()
    for name in ("cofii2p", "icl"):
        expected = score(records, installed.find(name).rules)
        assert table[f"{name} Acc. (%)"].iloc[0] == round(expected["acc_pct"], 2)
        assert table[f"{name} RRE (°)"].iloc[0] == f"{expected['rre_mean']:.2f} ± {expected['rre_std']:.2f}"


def test_evaluate_refuses_rules_with_thresholds_and_rules_only_alone(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path), "--rules", "all", "--acc-rre", "3"]) == 2
    assert "--acc-rre and --rules do not go together" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path), "--rules-only"]) == 2
    assert "--rules-only goes with --rules" in capsys.readouterr().err
