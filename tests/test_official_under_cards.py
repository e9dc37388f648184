"""The official sizes under their own protocol cards: a frame the card built (`Frame.inputs`) already is the authors'
loader's inputs (the 160 x 512 crop, the drawn 0.1 m voxels in the camera frame), so the stages take it as it is:
the crop's own cells, the frame's points in order, no axis permutation. Another card's frame is refused by name (the
image used to be halved and cropped twice into zero cells and camera axes turned as the LiDAR's)."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pandas as pd
import pytest
import torch
from i2pbench_corri2p.official.stages import LOADER_CARDS as CORRI2P_CARDS
from i2pbench_corri2p.official.stages import pixel_cells as corri2p_cells
from i2pbench_deepi2p.official.stages import CROP as DEEPI2P_CROP
from i2pbench_deepi2p.official.stages import LOADER_CARDS as DEEPI2P_CARDS
from i2pbench_deepi2p.official.stages import OfficialFrustum, crop_K
from i2pbench_deepi2p.official.stages import pixel_cells as deepi2p_cells
from i2pbench_vp2p_match.official.prepare import pixel_cells as vp2p_cells
from i2pbench_vp2p_match.official.stages import LOADER_CARDS as VP2P_CARDS

from i2pbench.api import Matches
from i2pbench.cli import main
from i2pbench.errors import StageError
from i2pbench.layers.peer_inputs import LIDAR_TO_CAMERA_AXES, frame_crop
from i2pbench.registry.build import default_registry
from i2pbench.scoring import installed
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import STAGE_ORDER, Combination, Pipeline
from i2pbench.types import SensorFrame

K = np.array([[700.0, 0.0, 620.0], [0.0, 700.0, 188.0], [0.0, 0.0, 1.0]])
T_CL = np.array([[0.0, -1.0, 0.0, 0.06], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27], [0.0, 0.0, 0.0, 1.0]])
OFFICIAL_EXTRACTORS = [
    ("extractor2d", "corri2p-official-grid"),
    ("extractor3d", "corri2p-official-points"),
    ("extractor2d", "vp2p-match-official-grid"),
    ("extractor3d", "vp2p-match-official-points"),
    ("extractor2d", "deepi2p-official-grid"),
    ("extractor3d", "deepi2p-official-points"),
]
# (size, a card whose frames are its authors' loader's inputs, its cell side in pixels of the crop)
UNDER_CARDS = [
    ("corri2p", "corri2p", 4),
    ("corri2p", "vp2p-match", 4),
    ("vp2p-match", "vp2p-match", 4),
    ("vp2p-match", "corri2p", 4),
    ("deepi2p", "deepi2p", 32),
]
FOREIGN = {"corri2p": "deepi2p", "vp2p-match": "deepi2p", "deepi2p": "corri2p"}  # a card whose inputs are not theirs


def sensor(points: np.ndarray | None = None) -> SensorFrame:
    """a 1241 x 376 frame with KITTI's shape of calibration; by default 600 random returns in front of the car."""
    if points is None:
        rng = np.random.default_rng(0)
        xyz = np.c_[rng.uniform(5, 40, 600), rng.uniform(-10, 10, 600), rng.uniform(-1.5, 1.0, 600)]
        points = np.c_[xyz, rng.uniform(0, 1, 600)].astype(np.float32)
    image = np.random.default_rng(1).integers(0, 256, (376, 1241, 3), dtype=np.uint8)
    return SensorFrame("kitti", "00/000000", image, points, np.zeros(len(points), np.int16), K, T_CL)


def ground() -> SensorFrame:
    """a flat ground 1.5 m below the LiDAR, one return every 0.25 m (each its own 0.1 m voxel): its normal is up."""
    x, y = np.meshgrid(np.arange(5.0, 30.0, 0.25), np.arange(-10.0, 10.0, 0.25))
    return sensor(np.c_[x.ravel(), y.ravel(), np.full(x.size, -1.5), np.full(x.size, 0.5)].astype(np.float32))


def card_frame(card: str, scene: SensorFrame | None = None):
    return installed.find(card).protocol(seed=0, dataset="kitti").apply(sensor() if scene is None else scene)


def component(kind: str, name: str, conf: dict | None = None):
    return default_registry().component(kind, name)(conf)


@pytest.fixture(scope="module")
def frames():
    return {card: card_frame(card) for card in ("corri2p", "vp2p-match", "deepi2p")}


@pytest.fixture(scope="module")
def matchers():
    return {size: component("matcher", f"{size}-official") for size in ("corri2p", "vp2p-match", "deepi2p")}


def test_a_frame_names_the_card_whose_inputs_it_holds():
    assert Protocol().apply(sensor()).inputs == ""  # the dataset's frame, in LiDAR axes
    assert installed.find("vp2p-match").protocol(seed=0, dataset="kitti").apply(sensor()).inputs == "vp2p-match"
    assert Protocol(pose_frame="camera").apply(sensor()).inputs == "edgeregnet"  # camera axes alone count


def test_each_official_size_declares_its_loader_cards():
    assert CORRI2P_CARDS == VP2P_CARDS == {"corri2p", "vp2p-match"}  # the same loader inputs (cards.py)
    assert DEEPI2P_CARDS == {"deepi2p"}
    for kind, name in OFFICIAL_EXTRACTORS:
        size = name.removesuffix("-official-grid").removesuffix("-official-points")
        assert default_registry().component(kind, name).loader_cards == {"corri2p": CORRI2P_CARDS,
                                                                         "vp2p-match": VP2P_CARDS,
                                                                         "deepi2p": DEEPI2P_CARDS}[size]  # fmt: skip


@pytest.mark.parametrize(("kind", "name"), OFFICIAL_EXTRACTORS)
def test_an_official_extractor_refuses_a_foreign_cards_frame_naming_the_cards_it_takes(kind, name):
    size = name.removesuffix("-official-grid").removesuffix("-official-points")
    stage, foreign = component(kind, name), FOREIGN[size]
    accepted = "'deepi2p'" if size == "deepi2p" else "'corri2p', 'vp2p-match'"
    points = 40960 if foreign == "corri2p" else 20480
    with pytest.raises(StageError, match=rf"takes them from protocol {accepted}, but protocol '{foreign}' gives the "
                                         rf"stages its own \(512 x 160 image, {points} points"):  # fmt: skip
        stage(card_frame(foreign))
    with pytest.raises(StageError, match="protocol 'edgeregnet'"):  # camera axes alone: not the authors' inputs
        stage(Protocol(pose_frame="camera").apply(sensor()))
    out = stage(Protocol().apply(sensor()))  # the dataset's own frame is prepared as before
    assert len(out.uv if kind == "extractor2d" else out.xyz) > 0


@pytest.mark.parametrize(("size", "card", "cell"), UNDER_CARDS)
def test_a_loader_cards_frame_of_another_size_than_the_authors_crop_is_refused(frames, size, card, cell):
    """the card's nuScenes frames are 320 x 160: not the KITTI network's crop, which the official size is."""
    narrow = dataclasses.replace(frames[card], image=np.ascontiguousarray(frames[card].image[:, :320]))
    with pytest.raises(StageError, match=rf"protocol '{card}' gives a 320 x 160 image, not the authors' 512 x 160"):
        component("extractor2d", f"{size}-official-grid")(narrow)


@pytest.mark.parametrize(("size", "card", "cell"), UNDER_CARDS)
def test_under_its_card_the_cells_are_the_crops_own_pixels(frames, size, card, cell):
    frame = frames[card]
    assert frame.image_size == (512, 160)
    uv = component("extractor2d", f"{size}-official-grid")(frame).uv
    columns, rows = 512 // cell, 160 // cell
    assert len(uv) == columns * rows == {4: 5120, 32: 80}[cell]
    np.testing.assert_array_equal(uv[[0, 1, columns, len(uv) - 1]],
                                  [[0, 0], [cell, 0], [0, cell], [512 - cell, 160 - cell]])  # fmt: skip
    expected = np.stack(np.meshgrid(np.arange(columns) * cell, np.arange(rows) * cell), -1).reshape(-1, 2)
    np.testing.assert_array_equal(uv, expected)  # every cell once, raster order, covering the whole image


@pytest.mark.parametrize(("size", "card", "cell"), UNDER_CARDS)
def test_under_its_card_the_points_are_the_frames_own_in_order(frames, size, card, cell):
    frame = frames[card]
    kp3d = component("extractor3d", f"{size}-official-points")(frame)
    assert len(kp3d) == len(frame.points) == {"deepi2p": 20480}.get(card, 40960)
    np.testing.assert_array_equal(kp3d.index, np.arange(len(frame.points)))
    np.testing.assert_array_equal(kp3d.xyz, frame.points[:, :3])
    np.testing.assert_array_equal(kp3d.reflectance, frame.points[:, 3])
    fewer = component("extractor3d", f"{size}-official-points", {"max_keypoints": 200})(frame)
    assert len(fewer) == 200 and len(set(fewer.index.tolist())) == 200  # a seeded draw of the card's points
    if size == "deepi2p":  # over twice 200 points: the loader's 0.3 m grid first, each its nearest point's row
        gap = np.linalg.norm(fewer.xyz - frame.points[fewer.index, :3], axis=1)
        assert 0 < gap.max() <= 0.3 * np.sqrt(3)
    else:
        np.testing.assert_array_equal(fewer.xyz, frame.points[fewer.index, :3])


@pytest.mark.parametrize(("size", "card", "cell"), UNDER_CARDS)
def test_under_its_card_the_network_reads_the_frame_unpermuted(frames, matchers, size, card, cell):
    frame = frames[card]
    kp2d = component("extractor2d", f"{size}-official-grid")(frame)
    kp3d = component("extractor3d", f"{size}-official-points", {"max_keypoints": 2000})(frame)
    inputs = matchers[size].prepare(frame, kp2d, kp3d)
    np.testing.assert_array_equal(inputs["pc"].T.numpy(), kp3d.xyz)  # T_init = I: network axes are the frame's
    np.testing.assert_array_equal(inputs["intensity"][0].numpy(), kp3d.reflectance)
    image = inputs["img" if size == "vp2p-match" else "image"].permute(1, 2, 0).numpy()
    scale = 1.0 if size == "deepi2p" else 255.0  # DeepI2P reads 0-255
    np.testing.assert_array_equal(image, frame.image.astype(np.float32) / np.float32(scale))  # the crop as it is
    normals = inputs["sn"].numpy()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=0), 1.0, atol=1e-5)
    assert (normals[1] <= 0).all()  # turned to camera up (-y)


@pytest.mark.parametrize("size", ["corri2p", "vp2p-match", "deepi2p"])
def test_a_flat_grounds_normal_is_camera_up_under_the_card_as_on_the_dataset_frame(matchers, size):
    card = "deepi2p" if size == "deepi2p" else size
    for frame in (card_frame(card, ground()), Protocol().apply(ground())):
        kp2d = component("extractor2d", f"{size}-official-grid")(frame)
        kp3d = component("extractor3d", f"{size}-official-points", {"max_keypoints": 500})(frame)
        normals = matchers[size].prepare(frame, kp2d, kp3d)["sn"].numpy()
        np.testing.assert_allclose(normals.T, np.tile([0.0, -1.0, 0.0], (len(kp3d), 1)), atol=1e-5)


# a scene point in the camera frame and where it lands: through the dataset frame's K (690, 223); through the card's
# K (x0.5, then the crop's offsets: 54 columns, 14 rows; DeepI2P: 50 rows cut first, then 1 row) at (291, 97.5) and
# (291, 85.5). Stride-4 cells: (690 - 108) / 8 = 72.75 and (223 - 28) / 8 = 24.4 on the dataset frame, 291 / 4 and
# 97.5 / 4 on the card's: cell 24 * 128 + 72 = 3144 on both, corner (8 * 72 + 108, 8 * 24 + 28) = (684, 220) there and
# (288, 96) = (684 / 2 - 54, 220 / 2 - 14) here. DeepI2P's 32 px cells: (690 - 108) / 64 = 9.1, (223 - 52) / 64 = 2.7,
# and 291 / 32, 85.5 / 32: cell 2 * 16 + 9 = 41, corner (684, 180) there and (288, 64) = (684 / 2 - 54, 130 / 2 - 1).
SCENE_POINT = np.array([1.0, 0.5, 10.0])
CELL_CHECKS = {  # size: (card K, the cell, its corner on the dataset frame, on the card's)
    "corri2p": ([[350, 0, 256], [0, 350, 80], [0, 0, 1]], 3144, (684, 220), (288, 96)),  # the loader's: no row cut
    "vp2p-match": ([[350, 0, 256], [0, 350, 80], [0, 0, 1]], 3144, (684, 220), (288, 96)),
    "deepi2p": ([[350, 0, 256], [0, 350, 68], [0, 0, 1]], 41, (684, 180), (288, 64)),
}
CELLS = {"corri2p": corri2p_cells, "vp2p-match": vp2p_cells, "deepi2p": deepi2p_cells}


def cell_of(size: str, frame, conf) -> int:
    crop = frame_crop(frame, conf, {"deepi2p": DEEPI2P_CARDS}.get(size, CORRI2P_CARDS), size)
    uv = (frame.K @ SCENE_POINT)[:2] / SCENE_POINT[2]
    width, height = frame.image_size
    return int(CELLS[size](uv[None].astype(np.float32), width, height, crop)[0])


@pytest.mark.parametrize("size", ["corri2p", "vp2p-match", "deepi2p"])
def test_a_scene_point_falls_in_the_same_cell_at_the_same_ray_under_the_card_as_on_the_dataset_frame(size):
    card_K, cell, dataset_corner, card_corner = CELL_CHECKS[size]
    dataset, card = Protocol().apply(sensor()), card_frame(size)
    np.testing.assert_array_equal(card.K, card_K)  # the card's K, hand-computed
    grid = component("extractor2d", f"{size}-official-grid")
    assert cell_of(size, dataset, grid.conf) == cell_of(size, card, grid.conf) == cell
    np.testing.assert_array_equal(grid(dataset).uv[cell], dataset_corner)
    np.testing.assert_array_equal(grid(card).uv[cell], card_corner)
    rays = [np.linalg.solve(f.K, [*corner, 1.0]) for f, corner in ((dataset, dataset_corner), (card, card_corner))]
    np.testing.assert_allclose(rays[0], rays[1], rtol=0, atol=1e-12)  # EPnP with the frame's K reads the same ray


def test_corri2ps_top_rows_stays_a_conf_that_cuts_the_dataset_frame_only():
    """`top_rows` = 50 (DeepI2P's cut, options.py's crop_original_top_rows) moves the dataset frame's cells 50 rows
    down: the scene point's row is (223 - 52) / 8 = 21.4, three cells above its default 24; a card's frame is
    already the crop, so the conf cuts nothing there."""
    grid = component("extractor2d", "corri2p-official-grid", {"top_rows": 50})
    assert grid.conf["top_rows"] == 50 and component("extractor2d", "corri2p-official-grid").conf["top_rows"] == 0
    assert cell_of("corri2p", Protocol().apply(sensor()), grid.conf) == 21 * 128 + 72
    assert cell_of("corri2p", card_frame("corri2p"), grid.conf) == 24 * 128 + 72


@pytest.mark.parametrize(("size", "card"), [("corri2p", "corri2p"), ("vp2p-match", "vp2p-match")])
def test_on_a_real_kitti_scan_the_card_frame_is_taken_as_it_is(shared_data, matchers, size, card):
    from i2pbench.data.kitti import KittiOdometry

    scan = KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")}).load("00/000000")
    frame = card_frame(card, scan)
    assert frame.inputs == card and frame.image_size == (512, 160) and len(frame.points) == 40960
    kp2d = component("extractor2d", f"{size}-official-grid")(frame)
    kp3d = component("extractor3d", f"{size}-official-points")(frame)
    assert len(kp2d) == 5120 and tuple(kp2d.uv[-1]) == (508, 156)
    np.testing.assert_array_equal(kp3d.index, np.arange(40960))
    np.testing.assert_array_equal(kp3d.xyz, frame.points[:, :3])
    inputs = matchers[size].prepare(frame, kp2d, kp3d)
    np.testing.assert_array_equal(inputs["pc"].T.numpy(), frame.points[:, :3])  # no axis permutation
    assert (inputs["sn"][1] <= 0).all()  # normals turned to camera up


def frame_rows(runs) -> pd.DataFrame:
    return pd.concat([pd.read_parquet(p) for p in runs.glob("*/frames/*.parquet")])


@pytest.mark.parametrize("size", ["corri2p", "vp2p-match"])
def test_the_preset_runs_a_kitti_frame_untrained_under_its_card(shared_data, tmp_path, size):
    torch.set_num_threads(1)
    runs = tmp_path / "runs"
    data = ["--dataset", "kitti", "--data-root", str(shared_data / "kitti_odometry"), "--split", "all", "--frames", "1"]
    small = ["--conf", "extractor3d.max_keypoints=2048", "--threads", "1", "--protocol", size]  # fewer points
    assert main(["run", "--preset", f"{size}-official", *data, *small, "--runs-dir", str(runs), "--quiet"]) == 0
    (row,) = frame_rows(runs).itertuples()
    assert row.weights == "untrained" and row.failed_component == ""  # no stage failed
    assert row.status == "failed" or row.rre_deg > 5 or row.rte_m > 2  # untrained: no honest success


def test_deepi2ps_stages_run_a_kitti_frame_untrained_under_its_card(shared_data):
    """the CLI refuses the deepi2p card on KITTI (it accumulates 3 sweeps, which a frame does not hold), so the
    stages run here on the card's frame of one real scan."""
    from i2pbench.data.kitti import KittiOdometry

    torch.set_num_threads(1)
    scan = KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")}).load("00/000000")
    frame = card_frame("deepi2p", scan)
    assert frame.inputs == "deepi2p" and frame.image_size == (512, 160) and len(frame.points) == 20480
    registry = default_registry()
    (row,) = registry.preset_rows("deepi2p-official")
    names = {kind: row[kind] for kind in STAGE_ORDER if kind in row}
    confs = {**row["confs"], "extractor3d": {"max_keypoints": 2048}}
    outcome = Pipeline.build(registry, Combination(names, confs)).eval().run(frame)
    assert outcome.failure is None  # no stage error
    records = {r.kind: r.output for r in outcome.records}
    assert len(records["extractor2d"]) == 80 and len(records["extractor3d"]) == 2048
    matches = records["matcher"]
    assert len(matches.frustum) == 2048 and matches.radius_px == pytest.approx(np.hypot(32, 32))  # the crop's px
    estimate = records["solver"]
    assert estimate.T is None or not_a_success(estimate.T, frame.T_gt)  # untrained: no honest success


def not_a_success(T: np.ndarray, T_gt: np.ndarray) -> bool:
    """RRE >= 5 deg or RTE >= 2 m (the peers' success threshold)."""
    diff = np.linalg.inv(T) @ T_gt
    angle = np.degrees(np.arccos(np.clip((np.trace(diff[:3, :3]) - 1) / 2, -1, 1)))
    return angle >= 5 or np.linalg.norm(diff[:3, 3]) >= 2


def test_deepi2ps_frustum_solver_under_its_card_reads_the_frames_points_and_k_as_they_are():
    """the same street scene given as the dataset's frame (LiDAR axes, full-size K) and as a deepi2p card's (camera
    axes, the crop's K, T_init = I): the frustum registration solves the same problem, so the card's pose is the
    dataset frame's without the axis permutation (camera <- camera-axes points)."""
    rng = np.random.default_rng(5)
    points = rng.uniform([-30, -20, -1.7], [40, 20, 3], (4000, 3))
    frustum = np.where(np.abs(points[:, 1]) < points[:, 0] * 0.4, 0.9, 0.1).astype(np.float32)  # ahead: inside
    matches = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), frustum)
    stage, scene = OfficialFrustum({"restarts": 4}), {"dataset": "toy", "frame_id": "street"}
    dataset = types.SimpleNamespace(K=K, image_size=(1241, 376), inputs="", **scene)
    card = types.SimpleNamespace(K=crop_K(K, 1241, 376, DEEPI2P_CROP), image_size=(512, 160), inputs="deepi2p",
                                 T_init=np.eye(4), **scene)  # fmt: skip
    ours = stage(dataset, None, types.SimpleNamespace(xyz=points), matches)
    in_camera = points @ LIDAR_TO_CAMERA_AXES.T.astype(np.float64)
    theirs = stage(card, None, types.SimpleNamespace(xyz=in_camera), matches)
    assert ours.ok and theirs.ok
    axes = np.eye(4)
    axes[:3, :3] = LIDAR_TO_CAMERA_AXES
    np.testing.assert_allclose(theirs.T @ axes, ours.T, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(theirs.inliers, ours.inliers)


def test_cofii2ps_points_take_only_a_cofii2p_card_frame_and_refuse_another_card_by_name():
    stage = component("extractor3d", "cofii2p-official-points")
    with pytest.raises(StageError, match=r"cofii2p-official-points: .*takes them from protocol 'cofii2p', but "
                                         r"protocol 'corri2p' gives the stages its own"):  # fmt: skip
        stage(card_frame("corri2p"))
    assert len(stage(Protocol().apply(sensor())).xyz) == 20480  # the dataset's 600 returns, repeated as the loader
