"""`i2pbench domain-gap`: per-frame statistics on hand-built frames, the side-by-side table, the CLI on real KITTI."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from i2pbench.api import Extractor2D, Extractor3D, Frame, Keypoints2D, Keypoints3D
from i2pbench.cli import main
from i2pbench.commands.domain_gap import STATISTICS
from i2pbench.diagnostics.domain_gap import (
    edge_counts,
    frame_statistics,
    gap_extractors,
    image_statistics,
    lidar_statistics,
    pair_statistics,
    side_by_side,
    summarize,
    to_markdown,
)
from i2pbench.registry.build import default_registry

ROOT = Path(__file__).resolve().parents[1]
K = np.array([[10.0, 0.0, 2.0], [0.0, 10.0, 2.0], [0.0, 0.0, 1.0]])  # a point on the optical axis lands on (2, 2)


def ramp_image() -> np.ndarray:
    """4x4 grey RGB image whose columns are 0, 10, 20, 30."""
    grey = np.tile(np.array([0, 10, 20, 30], np.uint8), (4, 1))
    return np.repeat(grey[:, :, None], 3, axis=2)


def hand_frame(match_radius_px: float = 3.0) -> Frame:
    """11 points: 7 on the optical axis 5 m ahead (they land on pixel (2, 2)), 4 behind the camera; ranges 5-55 m in
    5 m steps, reflectance 0, 0, 0.1, ..., 0.9, four distinct rings."""
    xyz = np.array([[0.0, 0.0, 5.0]] * 7 + [[0.0, 0.0, -5.0]] * 4)
    reflectance = np.array([0.0, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
    return Frame(
        dataset="hand", frame_id="0", image=ramp_image(),
        points=np.column_stack([xyz, reflectance]).astype(np.float32),
        ring=np.array([0, 0, 0, 1, 1, 1, 2, 2, 2, 5, 5], np.int16),
        ranges=np.arange(5.0, 60.0, 5.0, dtype=np.float32), K=K, T_gt=np.eye(4), match_radius_px=match_radius_px,
    )  # fmt: skip


class CentrePixel(Extractor2D):
    name = "centre"

    def __call__(self, frame: Frame) -> Keypoints2D:
        assert frame.T_gt is None  # an extractor never sees the ground truth
        return Keypoints2D(uv=np.array([[2.0, 2.0]], np.float32))


class FourPoints(Extractor3D):
    name = "four"

    def __call__(self, frame: Frame) -> Keypoints3D:
        assert frame.T_gt is None
        return Keypoints3D.from_index(frame, np.array([0, 1, 9, 10]))  # two in front of the camera, two behind


def test_lidar_statistics_of_a_hand_built_scan():
    stats = lidar_statistics(hand_frame())
    # sorted ranges 5, 10, ..., 55: the q-th percentile sits at position q/100 * 10, an exact sample
    assert stats["points"] == 11 and stats["in_fov"] == pytest.approx(7 / 11)
    assert (stats["range_q10"], stats["range_q50"], stats["range_q90"]) == pytest.approx((10.0, 30.0, 50.0))
    assert stats["range_over_40m"] == pytest.approx(3 / 11)  # 45, 50, 55
    assert (stats["reflectance_q10"], stats["reflectance_q50"], stats["reflectance_q90"]) == pytest.approx(
        (0.0, 0.4, 0.8), abs=1e-6
    )  # positions 1, 5, 9 of 0, 0, 0.1, ..., 0.9 (float32)
    assert stats["reflectance_zero"] == pytest.approx(2 / 11)
    assert stats["rings"] == 4


def test_image_statistics_of_a_horizontal_ramp():
    frame = hand_frame()
    stats = image_statistics(frame, gradient_threshold=50.0)
    assert stats["grey_mean"] == 15.0
    assert stats["grey_std"] == pytest.approx(math.sqrt(125.0))  # deviations -15, -5, 5, 15
    # Sobel dx in the inner columns: (20 - 0) * (1 + 2 + 1) = 80; the reflected border (column -1 reads column 1)
    # gives 0 in the outer columns. So eight pixels of 0 and eight of 80.
    assert stats["gradient_mean"] == pytest.approx(40.0)
    assert stats["gradient_q90"] == pytest.approx(80.0)  # position 13.5 of 16 sorted values falls among the 80s
    assert stats["strong_gradient"] == 0.5
    assert image_statistics(frame)["strong_gradient"] == 0.0  # nothing reaches the default threshold of 150


def test_edge_counts_and_the_lift_come_from_the_extractors_given():
    frame = hand_frame(match_radius_px=1.0)
    assert edge_counts(frame, {"lsd": CentrePixel(), "depth": FourPoints()}) == {"lsd_pixels": 1.0, "depth_points": 4.0}
    stats = pair_statistics(frame, CentrePixel(), FourPoints())
    # both points in front land on the one keypoint; only pixel (2, 2) itself is closer than 1 px to it
    assert stats == pytest.approx({"ratio_in_fov": 1.0, "coverage2d": 1 / 16, "lift": 16.0})


def test_the_registered_extractors_count_uncapped_and_every_statistic_is_documented():
    extractors = gap_extractors(default_registry())
    assert {name: e.conf["max_keypoints"] for name, e in extractors.edges.items()} == dict.fromkeys(
        ["lsd", "canny", "depth", "reflectance", "depth+reflectance"]
    )
    assert (extractors.pair2d.name, extractors.pair3d.name) == ("lsd", "depth+reflectance")
    assert extractors.pair2d.conf["max_keypoints"] == extractors.pair3d.conf["max_keypoints"] == 3000  # diagnose's
    stats = frame_statistics(hand_frame(), extractors)
    assert ["frames", *stats] == list(STATISTICS)
    page = (ROOT / "docs" / "diagnose.md").read_text()
    assert [name for name in STATISTICS if f"`{name}`" not in page] == []


def test_the_side_by_side_table_gives_mean_std_ratio_and_difference():
    mine = summarize(pd.DataFrame({"points": [100.0, 300.0], "in_fov": [0.1, 0.3]}))
    theirs = summarize(pd.DataFrame({"points": [50.0], "in_fov": [0.0]}))
    table = side_by_side(mine, theirs, ("syn", "real")).set_index("statistic")
    assert list(table.columns) == ["syn mean", "syn std", "real mean", "real std", "ratio", "difference"]
    assert table.loc["frames", ["syn mean", "real mean", "ratio", "difference"]].tolist() == [2.0, 1.0, 2.0, 1.0]
    assert table.loc["points"].tolist() == pytest.approx([200.0, 100.0, 50.0, 0.0, 4.0, 150.0])
    assert math.isnan(table.loc["in_fov", "ratio"])  # no ratio against a mean of 0
    assert table.loc["in_fov", "difference"] == pytest.approx(0.2)
    markdown = to_markdown(table.reset_index()).splitlines()
    assert markdown[2] == "| frames | 2 | - | 1 | - | 2 | 1 |"
    assert markdown[3] == "| points | 200 | 100 | 50 | 0 | 4 | 150 |"
    assert markdown[4] == "| in_fov | 0.2 | 0.1 | 0 | 0 | - | 0.2 |"


def test_the_command_sets_two_real_kitti_sets_side_by_side(shared_data, tmp_path):
    out = tmp_path / "gap.csv"
    cmd = [sys.executable, "-m", "i2pbench.cli", "domain-gap", "--dataset", "kitti", "--split", "all",
           "--data-root", str(shared_data / "kitti_odometry"), "--against", "kitti", "--against-split", "all",
           "--against-root", str(shared_data / "kitti_real"), "--frames", "2", "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    first, second = "kitti/all (kitti_odometry)", "kitti/all (kitti_real)"  # equal names: told apart by root
    assert done.stdout.splitlines()[0] == (
        f"| statistic | {first} mean | {first} std | {second} mean | {second} std | ratio | difference |"
    )
    table = pd.read_csv(out).set_index("statistic")
    assert list(table.index) == list(STATISTICS)
    assert table.loc["frames", f"{first} mean"] == table.loc["frames", f"{second} mean"] == 2
    assert 110_000 <= table.loc["points", f"{first} mean"] <= 127_000  # HDL-64E sweeps (shared/data/README.md)
    assert table.loc["rings", f"{first} mean"] == 64
    lsd = table.loc["lsd_pixels"]
    assert lsd["ratio"] == pytest.approx(lsd[f"{first} mean"] / lsd[f"{second} mean"])
    assert table.loc["lsd_pixels", f"{first} mean"] > 3000  # uncapped
    assert (table.loc["lift", [f"{first} mean", f"{second} mean"]] > 1).all()


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--against", "kitty"], "unknown dataset 'kitty'; did you mean 'kitti'?"),
        (["--against", "kitti", "--against-root", "NOWHERE"], "sequences not found"),
        (["--against", "synthetic", "--out", "gap.txt"], "expected a .csv or .md file"),
    ],
    ids=["name", "root", "out-suffix"],
)
def test_a_bad_dataset_or_output_is_one_error_line(args, named, shared_data, tmp_path, capsys):
    args = [a.replace("NOWHERE", str(tmp_path / "nowhere")) for a in args]
    root = str(shared_data / "kitti_odometry")
    kitti = ["--dataset", "kitti", "--split", "all", "--data-root", root, "--frames", "1"]
    assert main(["domain-gap", *kitti, *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # refused before any frame was read
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("i2pbench: error:") and named in lines[0], captured.err
