import json
import math

import numpy as np
import pandas as pd
import pytest
from conftest import SAMPLE_DATA, needs_sample
from scipy.spatial.transform import Rotation

from i2pbench.geometry.transforms import make_transform, rot_z
from i2pbench.scoring.pose import kept, pose_errors
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.rules import ScoringRules
from i2pbench.scoring.score import summarize

VECTORS = SAMPLE_DATA / "metric_vectors.json"


def test_yaw_of_90_degrees_gives_rre_90_and_zero_rte():
    T_gt = make_transform(Rotation.from_euler("y", 90, degrees=True).as_matrix(), np.zeros(3))
    e = pose_errors(np.eye(4), T_gt)
    assert e.rre_deg == pytest.approx(90.0)
    assert e.geodesic_deg == pytest.approx(90.0)
    assert e.rte_m == pytest.approx(0.0)


def test_known_translation_gives_its_norm_as_rte():
    e = pose_errors(np.eye(4), make_transform(np.eye(3), np.array([3.0, 4.0, 12.0])))
    assert e.rte_m == pytest.approx(13.0)
    assert e.rre_deg == pytest.approx(0.0)


def test_rte_is_measured_in_the_predicted_frame():
    # P_diff = inv(T_pred) @ T_gt: with T_pred a 90 deg yaw about z and T_gt a pure translation (1, 0, 0),
    # P_diff's translation is R_pred^T @ (1, 0, 0) = (0, -1, 0): norm 1, and the rotation error is 90 deg.
    T_pred = make_transform(rot_z(np.pi / 2), np.zeros(3))
    e = pose_errors(T_pred, make_transform(np.eye(3), np.array([1.0, 0.0, 0.0])))
    assert e.rte_m == pytest.approx(1.0)
    assert e.rre_deg == pytest.approx(90.0)


def test_rre_sums_absolute_extrinsic_xzy_angles():
    # extrinsic x=10, z=-20, y=30: the peers' RRE is 10 + 20 + 30 = 60, while the geodesic angle is smaller.
    R = Rotation.from_euler("xzy", [10, -20, 30], degrees=True).as_matrix()
    e = pose_errors(np.eye(4), make_transform(R, np.zeros(3)))
    assert e.rre_deg == pytest.approx(60.0)
    assert e.geodesic_deg < 60.0


def test_failed_solve_has_infinite_errors():
    e = pose_errors(None, np.eye(4))
    assert math.isinf(e.rte_m) and math.isinf(e.rre_deg) and math.isinf(e.geodesic_deg)


@needs_sample("metric_vectors.json")
def test_shared_metric_vectors():
    cases = json.loads(VECTORS.read_text())["cases"]
    assert len(cases) >= 4
    for case in cases:
        e = pose_errors(np.array(case["T_pred"]), np.array(case["T_gt"]))
        assert e.rte_m == pytest.approx(case["rte_m"], abs=1e-6), case["name"]
        assert e.rre_deg == pytest.approx(case["rre_deg_xzy_sum"], abs=1e-4), case["name"]
        assert e.geodesic_deg == pytest.approx(case["rre_deg_geodesic"], abs=1e-4), case["name"]


def _errors(rte: list[float], rre: list[float]) -> pd.DataFrame:
    """per-frame errors as `scoring.score.frame_errors` gives them, every frame scored."""
    return pd.DataFrame({"rte": rte, "rre": rre, "failed": np.isinf(rte), "scored": True})


def test_accuracy_counts_every_frame_and_filtering_keeps_only_good_ones():
    # five frames: two successes, one "kept but not successful" (RRE 7), one outlier (RTE 6), one failed solve.
    rte, rre = [0.5, 1.5, 1.0, 6.0, np.inf], [1.0, 3.0, 7.0, 2.0, np.inf]
    s = summarize(_errors(rte, rre), ScoringRules())
    assert s["acc_pct"] == pytest.approx(40.0)  # 2 of 5
    assert s["kept"] == 3  # RRE < 10 and RTE < 5
    assert kept(pd.Series(rte), pd.Series(rre), Protocol()).tolist() == [True, True, True, False, False]
    assert s["rte_mean"] == pytest.approx(1.0)  # (0.5 + 1.5 + 1.0) / 3
    assert s["rre_mean"] == pytest.approx(11.0 / 3)
    assert s["rte_std"] == pytest.approx(np.std([0.5, 1.5, 1.0]))


def test_thresholds_are_parameters():
    strict = ScoringRules(acc_rre_deg=2.0, acc_rte_m=1.0)
    assert summarize(_errors([0.5, 1.5], [1.0, 3.0]), strict)["acc_pct"] == pytest.approx(50.0)
    loose = Protocol(rules=ScoringRules(filter_rte_m=1.0))
    assert kept(pd.Series([0.5, 1.5]), pd.Series([1.0, 3.0]), loose).tolist() == [True, False]


def test_no_kept_frames_gives_nan_means():
    s = summarize(_errors([np.inf], [np.inf]), ScoringRules())
    assert s["acc_pct"] == 0.0 and np.isnan(s["rte_mean"])
