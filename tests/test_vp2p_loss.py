"""VP2P-Match's training loss (official/loss.py): adapt_loss and det_loss by hand and against the authors' own
utils/loss.py on the reference set's network outputs (checkout from I2PBENCH_VP2P_CHECKOUT), the anchors and the
stride-4 camera by hand, and training the official size on a real KITTI frame: in process (the loss falls over a
few steps on one frame) and through `i2pbench train` (a checkpoint that `run --weights` names in its row)."""

from __future__ import annotations

import importlib.util
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import sample
from i2pbench_vp2p_match.official.loss import adapt_loss, anchors, cell_camera, det_loss, frame_loss
from i2pbench_vp2p_match.official.prepare import grid_pixels
from i2pbench_vp2p_match.official.stages import CROP, SUP, unpadded

from i2pbench.api import Features, StageError
from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import expand
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Pipeline
from i2pbench.training.batching import collate
from i2pbench.training.lineage import continued
from i2pbench.training.trainable import check_trainable
from i2pbench.weights.checkpoints import data_label, load_checkpoint

CHECKOUT = os.environ.get("I2PBENCH_VP2P_CHECKOUT")
REFERENCE = Path(os.environ.get("I2PBENCH_VP2P_REFERENCE") or Path(__file__).parent / "data" / "vp2p_reference")
# the authors' network at a small size: a 256 x 96 crop, 1,024 points, 128 anchors, 128 Monte-Carlo samples
SMALL = ["extractor3d.max_keypoints=1024", "extractor2d.crop=[256,96]", "matcher.crop=[256,96]",
         "matcher.num_kpt=128", "matcher.pose_samples=128"]  # fmt: skip


def softplus(x: float) -> float:
    return math.log1p(math.exp(x))


def lse(*xs: float) -> float:
    return math.log(sum(math.exp(x) for x in xs))


def test_adapt_loss_on_two_pixels_and_two_points_by_hand():
    img = torch.tensor([[[1.0, 0.0], [0.0, 1.0]]])  # pixel 0 = (1, 0), pixel 1 = (0, 1)
    pc = torch.tensor([[[1.0, 0.6], [0.0, 0.8]]])  # point 0 = (1, 0), point 1 = (0.6, 0.8)
    loss, sim = adapt_loss(img, pc, torch.eye(2)[None], margin=0.25, gamma=1.0)
    assert torch.allclose(sim, torch.tensor([[[1.0, 0.6], [0.0, 0.8]]]))
    # positives 1 and 0.8: alpha_p = 1.25 - s, logit -alpha_p (s - 0.75): -0.0625, -0.0225; masked entries: 0.
    # negatives 0.6 and 0 (an exact 0 counts as masked): alpha_n = s + 0.25, logit alpha_n (s - 0.25): 0.2975, 0.
    rows = softplus(lse(-0.0625, 0) + lse(0, 0.2975)) + softplus(lse(0, -0.0225) + lse(0, 0))
    cols = softplus(lse(-0.0625, 0) + lse(0, 0)) + softplus(lse(0, -0.0225) + lse(0.2975, 0))
    assert loss.item() == pytest.approx(rows / 2 + cols / 2, abs=1e-6)


def test_det_loss_by_hand():
    loss = det_loss(torch.tensor([0.9, 0.7]), torch.tensor([0.2]), torch.tensor([1.0]), torch.tensor([0.1, 0.3]))
    assert loss.item() == pytest.approx((1 - 0.8) + 0.0 + 0.2 + 0.2, abs=1e-7)


def test_anchors_by_hand():
    K4 = np.array([[10.0, 0, 2], [0, 10, 1.5], [0, 0, 1]])  # a 4 x 3 map
    pc = np.array([[0, 0.1, 0.5, 0], [0, 0.1, 0, 0], [1, 1, 1, -1]], float)  # -> (2, 1.5), (3, 2.5), (7, 1.5), behind
    got = anchors(pc, K4, np.eye(3), np.zeros(3), (4, 3), 10, 1.0, np.random.default_rng(0))
    order = np.argsort(got["pc_kpt_idx"])
    assert sorted(got["pc_kpt_idx"]) == [0, 1] and sorted(got["pc_outline_idx"]) == [2, 3]
    assert got["img_kpt_idx"][order].tolist() == [6, 11]  # cells (2, 1) and (3, 2)
    assert sorted(got["img_outline_idx"]) == [c for c in range(12) if c not in (6, 11)]
    assert got["img_xy"][order].tolist() == [[2, 1], [3, 2]]
    # point 0 lies 0.5 from its cell's corner, 1.8 from the other's; point 1: 0.5 and 1.1
    assert np.array_equal(got["correspondence"][np.ix_(order, order)], np.eye(2))


def test_the_stride_4_camera_puts_each_cells_pixel_at_its_cell():
    K = np.array([[718.856, 0, 607.19], [0, 718.856, 185.22], [0, 0, 1]])
    pixels = grid_pixels(1242, 375, CROP)
    K4 = cell_camera(K, 1242, 375, CROP, 4)
    rays = np.linalg.inv(K) @ np.c_[pixels, np.ones(len(pixels))].T * 12.5
    cells = K4 @ rays
    cells = (cells[:2] / cells[2]).T
    rows, cols = np.divmod(np.arange(len(pixels)), 512 // 4)
    assert np.abs(cells - np.c_[cols, rows]).max() < 1e-9


@pytest.fixture(scope="module")
def authors_loss():
    if not CHECKOUT or not (Path(CHECKOUT) / "utils" / "loss.py").is_file():
        pytest.skip("set I2PBENCH_VP2P_CHECKOUT to a junshengzhou/VP2P-Match checkout to compare with utils/loss.py")
    spec = importlib.util.spec_from_file_location("vp2p_authors_loss", Path(CHECKOUT) / "utils" / "loss.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_adapt_and_det_loss_equal_the_authors_on_the_reference_outputs(authors_loss):
    if not (REFERENCE / "outputs.npz").is_file():
        pytest.skip(f"no VP2P-Match reference vectors at {REFERENCE}")
    out = np.load(REFERENCE / "outputs.npz")
    pixels = torch.from_numpy(out["network.pixel_feat"]).double().flatten(1)
    points = torch.from_numpy(out["network.point_feat"]).double()
    rng = np.random.default_rng(0)
    n = 64
    pick_px, pick_pt = (torch.from_numpy(rng.choice(x.shape[1], 2 * n, replace=False)) for x in (pixels, points))
    mask = torch.from_numpy(rng.random((n, n)) < 0.05).double()
    mask[torch.arange(n), torch.from_numpy(rng.integers(0, n, n))] = 1  # every pixel has a true point
    values, grads = [], []
    for fn in (adapt_loss, authors_loss.adapt_loss):
        img = pixels[:, pick_px[:n]][None].clone().requires_grad_(True)
        pc = points[:, pick_pt[:n]][None].clone().requires_grad_(True)
        loss, _ = fn(img, pc, mask[None], 0.25, 32)
        loss.backward()
        values.append(loss.item())
        grads.append((img.grad, pc.grad))
    assert values[0] == pytest.approx(values[1], rel=1e-12)
    for ours, theirs in zip(grads[0], grads[1], strict=True):
        assert (ours - theirs).abs().max() <= 1e-12 * theirs.abs().max()
    img_score = torch.from_numpy(out["network.img_score"]).double().flatten()
    pc_score = torch.from_numpy(out["network.pc_score"]).double().flatten()
    parts = (img_score[pick_px[:n]], img_score[pick_px[n:]], pc_score[pick_pt[:n]], pc_score[pick_pt[n:]])
    theirs = authors_loss.det_loss(*parts, None, mask[None])
    assert det_loss(*parts).item() == pytest.approx(theirs.item(), rel=1e-12)


@pytest.fixture(scope="module")
def small_stage():
    """the official size at SMALL, its matcher in training mode, and a KITTI frame's prepared inputs."""
    torch.set_num_threads(1)
    torch.manual_seed(0)
    registry = default_registry()
    confs: dict = {}
    for item in SMALL:
        key, value = item.split("=")
        kind, name = key.split(".")
        confs.setdefault(kind, {})[name] = eval(value)  # ints and lists written above
    (row,) = registry.preset_rows("vp2p-match-official")
    pipeline = Pipeline.build(registry, expand([row], {}, confs, registry)[0])
    dataset = registry.dataset("kitti")("all", {"root": str(sample("kitti_odometry"))})
    frame = Protocol(seed=1).apply(dataset.load(dataset.frame_ids()[0]))
    stages = pipeline.stages
    matcher = stages["matcher"].train()
    return pipeline, matcher, matcher.one(frame, stages["extractor2d"](frame), stages["extractor3d"](frame)), dataset


def prepared(pipeline, dataset, index: int) -> dict[str, torch.Tensor]:
    frame = Protocol(seed=index).apply(dataset.load(dataset.frame_ids()[index]))
    stages = pipeline.stages
    return stages["matcher"].prepare(frame, stages["extractor2d"](frame), stages["extractor3d"](frame))


def test_the_official_size_trains_and_its_loss_falls_on_one_frame(small_stage):
    pipeline, matcher, inputs, _ = small_stage
    assert check_trainable(pipeline) is matcher
    assert int(inputs["sup_num_pc_kpt_idx"][0]) >= 20  # in-view anchors of the frame under its transform
    optimizer = torch.optim.Adam(matcher.parameters(), lr=1e-3)
    losses = []
    for _ in range(3):
        loss, terms = matcher.batch_loss(inputs, Features(None, None), None, None)
        assert set(terms) == {"desc", "det", "pose", "anchors"} and all(math.isfinite(v) for v in terms.values())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[0] > losses[1] > losses[2] and losses[2] < 0.6 * losses[0]  # 68.8, 46.3, 36.4 here


def test_a_padded_batch_of_two_frames_gives_each_frame_its_own_anchors(small_stage):
    pipeline, matcher, _, dataset = small_stage
    frames = [prepared(pipeline, dataset, i) for i in (1, 2)]
    few = frames[0]  # as a frame with fewer points in view: its first 100 anchors, padded in the batch
    for key in ("sup_pc_kpt_idx", "sup_img_kpt_idx", "sup_img_xy"):
        few[key] = few[key][:100]
    few["sup_correspondence"], few["sup_num_pc_kpt_idx"] = few["sup_correspondence"][:100, :100], torch.tensor(100)
    batch = collate(frames)
    padded = {k.removeprefix(SUP): v for k, v in batch.items() if k.startswith(SUP)}
    own = [unpadded({k.removeprefix(SUP): v[None] for k, v in f.items() if k.startswith(SUP)}, 0) for f in frames]
    for b, anchors_b in enumerate(own):
        cut = unpadded(padded, b)
        assert cut.keys() == anchors_b.keys() and all(torch.equal(cut[k], anchors_b[k]) for k in cut)
    matcher.eval()  # BatchNorm from its running statistics: the two forward passes below agree
    try:
        with torch.no_grad():
            together, terms = matcher.batch_loss(batch, Features(None, None), None, None)
            out = matcher.batched(batch)
    finally:
        matcher.train()
    each = [frame_loss({k: v[b] for k, v in out.items()}, own[b], frames[b]["pc"], matcher.conf) for b in (0, 1)]
    assert together.item() == pytest.approx((each[0]["loss"].item() + each[1]["loss"].item()) / 2, rel=1e-6)
    assert terms["anchors"] == (100 + int(frames[1]["sup_num_pc_kpt_idx"])) / 2


def test_a_frame_without_its_true_pose_is_refused_for_training(small_stage):
    _, matcher, inputs, _ = small_stage
    network_only = {k: v for k, v in inputs.items() if not k.startswith(SUP)}
    with pytest.raises(StageError, match="true pose"):
        matcher.batch_loss(network_only, Features(None, None), None, None)


def test_fine_tuning_the_authors_release_names_it_in_the_lineage():
    release = {"release": "authors' release (KITTI)"}
    now = {"dataset": "nuscenes", "split": "train", "root": "/data/nuscenes", "frames": 28130}
    history, new_phase = continued([], release, now, 0)
    assert new_phase and history == [{"dataset": None, "split": None, "root": None, **release, "steps": 0}]
    assert [data_label(d) for d in history] == ["authors' release (KITTI)"]


def test_train_writes_a_checkpoint_that_run_names(shared_data, tmp_path):
    data = ["--dataset", "kitti", "--data-root", str(shared_data / "kitti_odometry"), "--split", "all"]
    small = [a for item in SMALL for a in ("--conf", item)] + ["--threads", "1", "--quiet"]
    out = tmp_path / "vp2p.pt"
    train = ["train", "--preset", "vp2p-match-official", *data, "--val-split", "none", "--out", str(out)]
    assert main([*train, "--steps", "1", "--cache-dir", str(tmp_path / "cache"), *small]) == 0
    checkpoint = load_checkpoint(out)
    assert checkpoint.meta["steps"] == 1 and checkpoint.meta["train_seconds"] > 0
    assert checkpoint.meta["trained_on"]["dataset"] == "kitti" and set(checkpoint.state) == {"matcher"}
    runs = tmp_path / "runs"
    run = ["run", "--preset", "vp2p-match-official", *data, "--frames", "1", "--weights", str(out)]
    assert main([*run, "--runs-dir", str(runs), *small]) == 0
    board = leaderboard.read(next((runs / "leaderboards").glob("*.csv")))
    assert board.iloc[0]["weights"].startswith("vp2p@") and "1 steps" in board.iloc[0]["weights_trained_on"]
