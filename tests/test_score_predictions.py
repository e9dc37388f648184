"""`i2pbench score`: foreign per-frame predictions scored under every card; a run's own poses exported to the
documented CSV score exactly as `evaluate --rules` scores the run; readers for the peers' saved outputs; bad input
named by file, row and column."""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

import i2pbench
from i2pbench.cli import main
from i2pbench.errors import DataError
from i2pbench.scoring import installed
from i2pbench.scoring.foreign import NEEDS_POSES
from i2pbench.scoring.predictions import GT, PRED, from_records, method_label
from i2pbench.scoring.table import columns

# the oracle under the strongest intrinsic error: RRE 3.5-9 deg, some frames under 5 deg and most not, so the cards'
# thresholds (5 deg; 10 deg for CoFiI2P) and DeepI2P's all-inliers rule all act (evaluate --rules reads one condition)
GRID = {"extractor2d": ["lsd", "canny"], "encoder2d": "none", "encoder3d": "none", "exchanger": "none",
        "matcher": "oracle", "solver": "epnp-ransac", "corruption": "intrinsic-error:5", "threads": 1,
        "quiet": True}  # fmt: skip


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A 20-frame run of two classic rows (40 predictions) and its poses in the documented CSV."""
    where = tmp_path_factory.mktemp("scored")
    result = i2pbench.run(frames=20, runs_dir=where / "runs", out=where / "board", **GRID)
    csv = where / "predictions.csv"
    from_records(result.records).to_csv(csv, index=False)
    return result, csv, where


def test_scoring_the_exported_csv_gives_evaluate_rules_numbers_under_every_card(exported):
    result, csv, where = exported
    assert len(pd.read_csv(csv)) == 40
    assert main(["score", str(csv), "--rules", "all", "--out", str(where / "scored")]) == 0
    scored = pd.read_csv(where / "scored.csv", dtype=str, keep_default_na=False).set_index("method")
    rules = i2pbench.evaluate(result.run_dir, rules="all", rules_only=True).board
    rules.index = [method_label(*row) for row in rules[["combination", "corruption", "severity"]].to_numpy()]
    cards = list(installed.installed())
    assert len(cards) >= 6 and sorted(scored.index) == sorted(rules.index)
    for card in cards:
        for column in columns(card):
            assert scored[column].to_dict() == rules[column].to_dict(), column
    assert {f"{card} {m} 95% CI" for card in cards for m in ("Acc.", "RTE", "RRE")} <= set(scored.columns)
    accs = [float(scored.loc[m, f"{card} Acc. (%)"]) for m in scored.index for card in ("edgeregnet", "cofii2p")]
    assert 0.0 < min(accs) < 100.0 and max(accs) == 100.0  # some frames pass 5 deg, all pass CoFiI2P's 10 deg


def test_the_python_call_scores_a_dataframe_as_the_command_scores_its_file(exported):
    _, csv, where = exported
    from_python = i2pbench.score(pd.read_csv(csv), rules="edgeregnet,corri2p")
    from_file = pd.read_csv(where / "scored.csv", dtype=str, keep_default_na=False)
    for column in from_python.board.columns.drop(["method", "frames"]):
        assert from_python.board[column].tolist() == from_file[column].tolist(), column


def one_frame(frame_id, T_pred, T_gt=None, success=True):
    T_gt = np.eye(4) if T_gt is None else T_gt
    return {"frame_id": frame_id, "sequence": "00", **dict(zip(PRED, np.ravel(T_pred), strict=True)),
            **dict(zip(GT, np.ravel(T_gt), strict=True)), "pnp_success": success}  # fmt: skip


def shifted(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[0, 3] = x
    return T


def test_hand_computed_numbers_and_intervals_under_the_edgeregnet_rules():
    # RTE 1, 3 and 0.5 m with RRE 0, 0 and 4 deg (a yaw about z is the peers' Euler 'xzy' middle angle), and a
    # failure: Acc. = 2 of 4 (1 m/0 deg and 0.5 m/4 deg); mean over RRE < 10 and RTE < 5: RTE (1 + 3 + 0.5) / 3 =
    # 1.5, std sqrt(((-.5)^2 + 1.5^2 + 1^2) / 3) = 1.08; RRE 4/3 = 1.33, std sqrt((2 * (4/3)^2 + (8/3)^2) / 3) = 1.89
    failed = one_frame("d", np.full(16, np.nan), success=False)
    table = pd.DataFrame([one_frame("a", shifted(1.0)), one_frame("b", shifted(3.0)), one_frame("c", shifted(0.5, 4.0)),
                          failed])  # fmt: skip
    row = i2pbench.score(table, rules="edgeregnet").board.iloc[0]
    assert row["frames"] == 4 and row["edgeregnet Acc. (%)"] == "50.00"
    assert row["edgeregnet RTE (m)"] == "1.50 ± 1.08" and row["edgeregnet RRE (°)"] == "1.33 ± 1.89"
    assert row["edgeregnet Acc. 95% CI"] == "[15.00, 85.00]"  # Wilson, 2 of 4: 0.5 -+ 0.35 (scipy's binomtest)


def test_bad_input_is_one_error_naming_the_file_row_and_column(tmp_path):
    sheared = np.eye(4)
    sheared[0, 1] = 0.3
    cases = {
        "rotation": ([one_frame("a", np.eye(4)), one_frame("b", sheared)], "row 1, columns T_pred_00..T_pred_22"),
        "nan": ([one_frame("a", np.eye(4), T_gt=np.where(np.eye(4) == 1, np.nan, 0.0))], "row 0, column T_gt_00"),
        "twice": ([one_frame("a", np.eye(4)), one_frame("b", np.eye(4)), one_frame("a", np.eye(4))],
                  "rows 0, 2, column frame_id: frame 'a'"),
    }  # fmt: skip
    for name, (rows, where) in cases.items():
        path = tmp_path / f"{name}.csv"
        pd.DataFrame(rows).to_csv(path, index=False)
        with pytest.raises(DataError) as raised:
            i2pbench.score(path)
        assert str(raised.value).startswith(f"{path}: {where}"), str(raised.value)
    assert main(["score", str(tmp_path / "twice.csv")]) == 2


def test_edgeregnet_kitti_xlsx_as_its_test_py_writes_it(tmp_path):
    pytest.importorskip("openpyxl")
    path = tmp_path / "KITTI.xlsx"
    data = {"RRE": [1.0, np.inf, 3.0], "RTE": [0.5, np.inf, 3.0]}  # test.py: lists, inf for a failed PnP
    pd.DataFrame(data).to_excel(path, index=True)  # as test.py saves it
    board = i2pbench.score(path).board.set_index("method")
    row = board.loc["EdgeRegNet test.py"]
    assert row["frames"] == 3 and row["edgeregnet Acc. (%)"] == "33.33"  # only frame 0 is under 5 deg and 2 m
    assert row["edgeregnet RTE (m)"] == "1.75 ± 1.25" and row["edgeregnet RRE (°)"] == "2.00 ± 1.00"
    assert row["deepi2p"] == NEEDS_POSES  # its rules (geodesic RRE, DeepI2P's failures) need the poses


def test_corri2p_result_error_folder_as_cal_error_all_writes_it(tmp_path):
    folder = tmp_path / "result_error_1.00_1.00_pos_margin_0.20_neg_margin_1.80"
    folder.mkdir()
    batches = {0: [shifted(1.0), shifted(0.0, 20.0)], 1: [shifted(2.5)]}
    for number, preds in batches.items():  # per test batch file: the sets its get_diff saves with np.save
        np.save(folder / f"T_pred_{number}.npy", np.array(preds))
        np.save(folder / f"T_gt_{number}.npy", np.array([np.eye(4)] * len(preds)))
        np.save(folder / f"is_success_{number}.npy", np.array([True] * len(preds)))
        np.save(folder / f"t_error_{number}.npy", np.array([p[0, 3] for p in preds]))
    scored = i2pbench.score(folder)
    assert scored.predictions["frame_id"].tolist() == ["0/0", "0/1", "1/0"]
    row = scored.board.iloc[0]
    assert row["corri2p Acc. (%)"] == "33.33"  # 1 m passes; 20 deg and 2.5 m do not


def test_cofii2p_eval_folder_as_eval_all_writes_it(tmp_path):
    for step, x in enumerate([0.5, 6.0]):  # cofii2p's bar: 10 deg and 5 m
        saved = {"GT_P": np.eye(4), "pred_P": shifted(x), "K": np.eye(3), "fine_xy": torch.zeros(2, 5)}
        np.save(tmp_path / f"{step:06d}.npy", saved)  # eval_all.py saves one pickled dict per step
    scored = i2pbench.score(tmp_path, rules="cofii2p")
    assert scored.predictions["frame_id"].tolist() == ["000000", "000001"]
    assert scored.board.iloc[0]["cofii2p Acc. (%)"] == "50.00"


def test_vp2p_match_error_arrays_saved_beside_each_other(tmp_path):
    t_err, r_err = np.array([0.4, 1.0, 3.0]), np.array([2.0, 6.0, 1.0])  # test_acc_trans's two return values
    np.save(tmp_path / "vp2p_t_error.npy", t_err)
    np.save(tmp_path / "vp2p_r_error.npy", r_err)
    row = i2pbench.score(tmp_path / "vp2p_r_error.npy", rules="vp2p-match").board.iloc[0]
    assert row["method"] == "vp2p" and row["vp2p-match Acc. (%)"] == "33.33"  # 6 deg and 3 m miss the bar
    np.save(tmp_path / "vp2p_t_error.npy", np.array([0.4, 1.0, np.inf]))  # a failure: the card makes it the identity
    assert i2pbench.score(tmp_path / "vp2p_t_error.npy", rules="vp2p-match").board.iloc[0]["vp2p-match"] == NEEDS_POSES


def test_the_documented_example_csv_scores_as_docs_python_md_says(tmp_path):
    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "predictions.csv"
    assert main(["score", str(example), "--out", str(tmp_path / "board")]) == 0
    board = pd.read_csv(tmp_path / "board.csv", dtype=str, keep_default_na=False)
    assert board["frames"].tolist() == ["20", "20"]
    for card in ("edgeregnet", "corri2p", "deepi2p", "vp2p-match"):
        assert board[f"{card} Acc. (%)"].tolist() == ["10.00", "10.00"], card
    assert board["cofii2p Acc. (%)"].tolist() == ["100.00", "100.00"]
    assert board["icl Acc. (%)"].tolist() == ["45.00", "35.00"]
    lsd = board.set_index("method").loc["lsd > depth+reflectance > oracle > epnp-ransac [intrinsic-error:5]"]
    assert lsd["edgeregnet RTE (m)"] == "1.20 ± 0.56" and lsd["edgeregnet RRE (°)"] == "6.47 ± 1.23"
