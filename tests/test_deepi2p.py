"""DeepI2P as a method: the conformance kit on every component at three sizes, the frustum-scores contract (declared,
checked, refused, stored and re-solved), hand-worked cell targets and pairing, the frustum solver on perfect scores,
a tiny configuration that learns one frame, batching, and the method's declaration."""

import dataclasses
import math
import subprocess
import sys

import i2pbench_deepi2p.plugin as deepi2p_plugin
import numpy as np
import pytest
import torch
from i2pbench_classic.extract2d import GridExtractor2D
from i2pbench_classic.extract3d import RandomExtractor3D
from i2pbench_deepi2p import configs
from i2pbench_deepi2p.classifier import DeepI2PClassifier, cell_targets, keypoint_of_cell
from i2pbench_deepi2p.extract import CellCentresExtractor
from i2pbench_deepi2p.fusion import DeepI2PFusion
from i2pbench_deepi2p.grid_matches import cell_keypoints, cell_matches
from i2pbench_deepi2p.image import DeepI2PImageEncoder
from i2pbench_deepi2p.labels import frustum_labels, grid_labels
from i2pbench_deepi2p.points import DeepI2PPointEncoder
from i2pbench_deepi2p.solver import FrustumSolver
from test_deepi2p_geometry import SIZE as TOY_SIZE
from test_deepi2p_geometry import T_CAM_LIDAR as TOY_T_CAM_LIDAR
from test_deepi2p_geometry import K as TOY_K
from test_deepi2p_geometry import scene
from test_edgeregnet_training import one_thread, tiny_frame  # noqa: F401 (an autouse fixture)
from test_training_batches import assert_mean_of_frames

from i2pbench.api import (
    FRUSTUM_SCORES,
    GROUND_TRUTH,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    Features,
    Frame,
    Keypoints2D,
    Keypoints3D,
    Matcher,
    Matches,
    PoseSolver,
    SensorFrame,
)
from i2pbench.errors import PluginError
from i2pbench.geometry.correspondence import true_match_mask
from i2pbench.registry.build import build_registry
from i2pbench.runs.grid import base_combinations, expand
from i2pbench.runs.jobs import prepare
from i2pbench.runs.upstream import UPSTREAM_KINDS, StoredUpstream
from i2pbench.scoring.metrics import true_matches
from i2pbench.scoring.pose import pose_errors
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.calling import StageInputs, call_stage
from i2pbench.stages.contracts import ContractError, check_matches
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.stages.trace import FrameOutcome, Upstream
from i2pbench.testing import check_component, check_declaration, registered_components
from i2pbench.training.batching import BatchForward, prepare_stage
from i2pbench.training.samples import collate_samples

D, G, CELL = 48, 16, 16
WIDTHS = {"descriptor_dim": D, "global_dim": G}
TINY = {
    "extractor2d": {"cell_px": CELL},
    "encoder2d": {
        **WIDTHS,
        "blocks": (1, 1, 1, 1),
        "channels": (8, 8, 16, 16),
        "stem_channels": 8,
        "image_scale": 1.0,
        "groups": 4,
    },
    "encoder3d": {
        **WIDTHS,
        "num_points": 1024,
        "sa1": {"npoint": 32, "radius": 0.2, "nsample": 16, "mlp": (8, 16)},
        "sa2": {"npoint": 32, "radius": 0.4, "nsample": 8, "mlp": (16, 32)},
        "global_mlp": (16, G),
        "fp_mlp": (32,),
        "head_mlp": (32,),
        "groups": 4,
    },
    "exchanger": {
        **WIDTHS,
        "attention_dim": 16,
        "point_nodes": 16,
        "frequencies": 3,
        "node_mlp": (32, 32),
        "point_mlp": (32,),
    },
    "matcher": {
        "descriptor_dim": D,
        "head_mlp": (32, 32),
        "dropout": 0.0,
        "cell_mlp": (16,),
        "frequencies": 3,
        "cell_px": CELL,
    },
    "solver": {"starts": 8},
}
KINDS = ("encoder2d", "encoder3d", "exchanger", "matcher")
CLASSES = (DeepI2PImageEncoder, DeepI2PPointEncoder, DeepI2PFusion, DeepI2PClassifier)
SIZES = {"paper": configs.PAPER, "cpu-size": configs.CPU, "tiny": TINY}


def tiny_modules() -> dict[str, torch.nn.Module]:
    torch.manual_seed(0)
    return {kind: cls(TINY[kind]) for kind, cls in zip(KINDS, CLASSES, strict=True)}


def tiny_cells(seed: int = 0) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    """the tiny 96 x 64 frame with the centres of its 16 px cells (6 x 4) as the 2D keypoints."""
    frame, _, kp3d = tiny_frame(seed)
    return frame, cell_keypoints(frame.image_size, CELL), kp3d


def features_of(stages, frame, kp2d, kp3d) -> Features:
    raw = Features(stages["encoder2d"](frame, kp2d), stages["encoder3d"](frame, kp3d))
    return stages["exchanger"](frame, kp2d, kp3d, raw)


# --- conformance

# the official size's stages (tests/test_deepi2p_official.py): the authors' crop scaled to the kit's small frame
OFFICIAL_TINY = {
    "deepi2p-official-grid": {"crop": (64, 32), "top_rows": 0},
    "deepi2p-official-points": {"max_keypoints": 1024},
    "deepi2p-official": {"crop": (64, 32), "top_rows": 0, "nodes": 16, "normals_points": 1024},
    "deepi2p-official-pnp": {},
    "deepi2p-official-frustum": {"crop": (64, 32), "top_rows": 0, "restarts": 2},
}
REGISTERED = registered_components(deepi2p_plugin)
COMPONENTS = [c for c in REGISTERED if c.name not in OFFICIAL_TINY]


@pytest.mark.parametrize("cls", COMPONENTS, ids=lambda c: c.name)
@pytest.mark.parametrize("size", list(SIZES))
def test_every_component_conforms(cls, size):
    conf = SIZES[size].get(cls.kind) if cls.kind in KINDS or size == "tiny" else None  # a size's solver is epnp's
    report = check_component(cls, conf)
    assert not list(report), str(report)


@pytest.mark.parametrize("cls", [c for c in REGISTERED if c.name in OFFICIAL_TINY], ids=lambda c: c.name)
def test_every_official_component_conforms(cls):
    report = check_component(cls, OFFICIAL_TINY[cls.name])
    assert not list(report), str(report)


def test_the_plugin_registers_the_method_s_components_and_the_frustum_solver():
    registered = [(c.kind, c.name) for c in COMPONENTS]
    expected = {**configs.EXTRACTORS, **configs.COMPONENTS, "solver": "deepi2p-frustum"}
    assert registered == [(k, v) for k, v in expected.items() if k != "extractor3d"]  # points: the classic `random`
    official = sorted((c.kind, c.name) for c in REGISTERED if c.name in OFFICIAL_TINY)
    assert official == sorted(
        [("extractor2d", "deepi2p-official-grid"), ("extractor3d", "deepi2p-official-points"),
         ("matcher", "deepi2p-official"), ("solver", "deepi2p-official-pnp"), ("solver", "deepi2p-official-frustum")]
    )  # fmt: skip


def test_parameter_counts_of_the_two_sizes():
    counts = {
        size: sum(p.numel() for kind, cls in zip(KINDS, CLASSES, strict=True) for p in cls(conf[kind]).parameters())
        for size, conf in (("paper", configs.PAPER), ("cpu-size", configs.CPU))
    }
    # measured when written: paper 25,557,826 (21.5 M of them the ResNet-34), cpu-size 814,946
    assert 20e6 < counts["paper"] < 30e6 and 0.5e6 < counts["cpu-size"] < 1.5e6


# --- the contract extension: frustum scores


class SilentMatcher(Matcher):
    """declares frustum scores and never gives them."""

    name = "silent"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})
    provides = frozenset({MATCHES, FRUSTUM_SCORES})

    def __call__(self, frame, kp2d, kp3d, features):
        return Matches.empty()


class TruthFrustum(Matcher):
    """perfect scores: every 3D keypoint's true frustum label, and each inside point matched to its cell's centre."""

    name = "truth-frustum"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, GROUND_TRUTH})
    provides = frozenset({MATCHES, FRUSTUM_SCORES})
    default_conf = {"cell_px": 64}

    def __call__(self, frame, kp2d, kp3d, features):
        xyz, size = kp3d.xyz.astype(np.float64), frame.image_size
        inside = frustum_labels(xyz, frame.K_true, frame.T_gt, size)
        cells = grid_labels(xyz, frame.K_true, frame.T_gt, size, self.conf["cell_px"])
        matches = cell_matches(cells, inside, self.conf["cell_px"])
        return dataclasses.replace(matches, frustum=inside.astype(np.float32))


def test_a_matcher_declaring_frustum_scores_must_return_them():
    frame, kp2d, kp3d = tiny_cells()
    with pytest.raises(ContractError, match="matcher 'silent'.*frustum_scores.*Matches.frustum None"):
        call_stage(SilentMatcher(), frame, StageInputs(kp2d, kp3d))
    problems = [p for p in check_component(SilentMatcher) if p.check == "contract"]
    assert problems and "Matches.frustum None" in problems[0].message


@pytest.mark.parametrize(
    ("frustum", "message"),
    [
        (np.full(4, 0.5, np.float32), r"frustum scores must be \[3\] \(one per 3D keypoint\), got \(4,\)"),
        (np.full((3, 1), 0.5, np.float32), r"must be \[3\]"),
        (np.array([0.5, 1.5, 0.0], np.float32), r"must lie in \[0, 1\]"),
        (np.array([0.5, np.nan, 0.0], np.float32), "NaN or inf"),
    ],
)
def test_wrong_frustum_scores_are_refused(frustum, message):
    matches = Matches(np.array([0]), np.array([1]), np.ones(1, np.float32), frustum=frustum)
    with pytest.raises(ContractError, match=message):
        check_matches(matches, 2, 3, "matcher 'x'")
    check_matches(dataclasses.replace(matches, frustum=np.array([0.0, 1.0, 0.25], np.float32)), 2, 3, "matcher 'x'")
    assert Matches.empty().frustum is None


def test_the_kit_knows_frustum_scores_and_who_provides_them():
    assert check_declaration(FrustumSolver) == [] and check_declaration(TruthFrustum) == []

    class ScoringSolver(PoseSolver):
        name = "scoring-solver"
        provides = frozenset({FRUSTUM_SCORES})

    (problem,) = check_declaration(ScoringSolver)
    assert problem.message == "provides ['frustum_scores'], which only frustum_scores by a matcher can carry"


def test_the_frustum_solver_after_a_matcher_without_scores_is_refused_at_build(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "classic,deepi2p")
    names = {"extractor2d": "deepi2p-cell-centres", "extractor3d": "random", "matcher": "oracle"}
    registry = build_registry(strict=True)
    with pytest.raises(PluginError) as refused:
        Pipeline.build(registry, Combination({**names, "solver": "deepi2p-frustum"}))
    assert str(refused.value) == (
        "solver 'deepi2p-frustum' needs frustum_scores, but matcher 'oracle' does not provide it"
    )


def toy_frame(seed: int = 0, n: int = 2000) -> Frame:
    """the geometry tests' toy scan (walls 8-24 m, elevations -25 to 25 deg) as a dataset frame of a 640 x 240
    camera, moved by the protocol's transform: its T_init is the calibration the frustum solver searches around."""
    points = np.c_[scene(n, np.random.default_rng(seed)), np.zeros(n)].astype(np.float32)
    image = np.zeros((TOY_SIZE[1], TOY_SIZE[0], 3), np.uint8)
    sensor = SensorFrame("toy", f"frustum-{seed}", image, points, np.zeros(n, np.int16), TOY_K, TOY_T_CAM_LIDAR)
    return Protocol(seed=seed).apply(sensor)


def perfect_frustum_pipeline() -> Pipeline:
    """cell centres, every point, perfect frustum scores and cells (TruthFrustum), the planar frustum solver."""
    stages = {
        "extractor2d": CellCentresExtractor(),
        "extractor3d": RandomExtractor3D({"max_keypoints": None}),
        "matcher": TruthFrustum(),
        "solver": FrustumSolver(),
    }
    return Pipeline(Combination({k: s.name for k, s in stages.items()}), stages, timeout_s=None)


@pytest.fixture(scope="module")
def perfect_frustum_run() -> tuple[Frame, Pipeline, FrameOutcome]:
    """the toy frame through the perfect frustum pipeline, solved once for the tests that read it (the planar
    solver's 52 local solves are most of their time)."""
    frame, pipeline = toy_frame(), perfect_frustum_pipeline()
    return frame, pipeline, pipeline.run(frame)


def test_a_pair_with_its_true_cell_is_a_true_match_judged_by_the_cell_not_by_eps_c(perfect_frustum_run):
    """Perfect grid classification: every point inside the image paired with its own cell's centre. Each projects
    inside its cell, so within the half diagonal (64 / sqrt 2 = 45.25 px) of the centre the pairs carry, and every
    pair counts as true; judged by eps_c (3 px) only those within 3 px of a centre would (about pi 3^2 / 64^2 = 0.7%
    of them), and a trained grid + PnP's every success would read as chance. The radius survives the stored upstream,
    and a file written without it reads back as eps_c."""
    frame, _, outcome = perfect_frustum_run
    assert outcome.matches.radius_px == pytest.approx(45.2548, abs=1e-4)
    pairs = len(outcome.matches)
    assert pairs > 100 and true_matches(frame, outcome) == pairs
    by_eps_c = true_match_mask(frame, outcome.matched_uv, outcome.matched_xyz).sum()
    assert by_eps_c < 0.05 * pairs

    arrays = StoredUpstream.of(frame, outcome).encode()
    assert StoredUpstream.decode(arrays).upstream.matches.radius_px == outcome.matches.radius_px
    del arrays["matches_radius_px"]
    assert StoredUpstream.decode(arrays).upstream.matches.radius_px is None


@pytest.mark.parametrize("radius", [0.0, -3.0, math.nan, math.inf])
def test_a_radius_that_is_no_positive_number_of_pixels_is_refused(radius):
    matches = Matches(np.array([0]), np.array([1]), np.ones(1, np.float32), radius_px=radius)
    with pytest.raises(ContractError, match="radius_px must be None or a positive number of pixels"):
        check_matches(matches, 2, 3, "matcher 'x'")
    check_matches(dataclasses.replace(matches, radius_px=45.25), 2, 3, "matcher 'x'")


def test_perfect_frustum_scores_give_the_pose_and_the_stored_upstream_gives_it_again(perfect_frustum_run, tmp_path):
    """Through the pipeline: cell centres, every point, perfect scores, the planar frustum solver. With every label
    honoured (cost 0), the poses the solver can end at are those that keep each point on its side of every face, so
    a border is pinned only to within the gap between the points beside it: 2,000 points over the scan's 5.3 sr
    (elevations +-25 deg) are 1 / sqrt(377 per sr) = 0.05 rad = 3 deg apart, whence the tolerance 2.5 deg and 0.75 m.
    Measured: 0.03 m, 0.12 deg here (seed 0); seeds 0-5 at most 0.35 m and 1.85 deg. The upstream stored as a run
    stores it (.npz) and read back re-solves to the very same pose."""
    frame, pipeline, outcome = perfect_frustum_run
    assert outcome.failure is None and outcome.matches.frustum.sum() > 100
    errors = pose_errors(outcome.estimate.T, frame.T_gt)
    assert errors.rte_m < 0.75 and errors.geodesic_deg < 2.5
    assert len(outcome.estimate.inliers) == len(outcome.matches)  # every match's point lies in the solved frustum

    np.savez(tmp_path / "upstream.npz", **StoredUpstream.of(frame, outcome).encode())
    with np.load(tmp_path / "upstream.npz") as arrays:
        stored = StoredUpstream.decode(arrays)
    np.testing.assert_array_equal(stored.upstream.matches.frustum, outcome.matches.frustum)
    assert stored.upstream.matches.frustum.dtype == np.float32
    again = pipeline.resolve(stored.solver_frame(), stored.upstream)
    np.testing.assert_array_equal(again.estimate.T, outcome.estimate.T)
    assert pipeline.resolvable


def test_an_upstream_without_frustum_scores_reads_back_as_none():
    frame, kp2d, kp3d = tiny_cells()
    matches = Matches(np.array([0, 1]), np.array([2, 3]), np.ones(2, np.float32))
    timings = dict.fromkeys(UPSTREAM_KINDS, 0.0)
    upstream = Upstream(kp2d, kp3d, matches)
    stored = StoredUpstream(upstream, timings, "tiny", "0", frame.K, frame.image_size, None, None, 3.0)
    arrays = stored.encode()
    assert "frustum" not in arrays
    assert StoredUpstream.decode(arrays).upstream.matches.frustum is None
    with pytest.raises(ValueError, match=r"frustum is \(5,\), not \(100,\)"):
        StoredUpstream.decode({**arrays, "frustum": np.zeros(5, np.float32)})


# --- the stages, worked by hand

# the labels tests' camera: looking along LiDAR +x, f = 100 px, centre (50, 40), a 100 x 80 image in 32 px cells:
# 3 rows (the last 16 px tall) of 4 columns (the last 4 px wide)
K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
T = np.eye(4)
T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
POINTS = np.array(
    [
        [10, 0, 0],  # -> (50, 40): cell row 1, column 1 = 5
        [10, 4.9, 3.9],  # -> (1, 1): cell 0
        [10, -4.9, -3.9],  # -> (99, 79): the partial corner cell 11
        [-10, 0, 0],  # behind the camera: outside
        [10, 5.2, 0],  # -> (-2, 40): outside, left of the image
        [10, -1.4, 0],  # -> (64, 40): cell 6 (columns 64..95)
    ],
    np.float32,
)


def labelled_frame(uv: np.ndarray) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    points = np.c_[POINTS, np.zeros(len(POINTS))].astype(np.float32)
    frame = Frame("toy", "cells", np.zeros((80, 100, 3), np.uint8), points, np.zeros(len(points), np.int16),
                  np.linalg.norm(POINTS, axis=1).astype(np.float32), K, T)  # fmt: skip
    return frame, Keypoints2D(np.asarray(uv, np.float32)), Keypoints3D.from_index(frame, np.arange(len(points)))


def test_cell_centres_are_the_grid_s_pixels_plus_the_partial_cells():
    frame = labelled_frame(np.zeros((0, 2)))[0]
    centres = CellCentresExtractor({"cell_px": 32})(frame).uv
    # columns 0..31, 32..63, 64..95, 96..99 -> 15.5, 47.5, 79.5, 97.5; rows 0..31, 32..63, 64..79 -> 15.5, 47.5, 71.5
    assert centres.tolist() == [[u, v] for v in (15.5, 47.5, 71.5) for u in (15.5, 47.5, 79.5, 97.5)]
    whole = GridExtractor2D({"stride": 32})(frame).uv  # the classic grid: whole cells only, the same centres
    assert whole.tolist() == [[u, v] for v in (15.5, 47.5) for u in (15.5, 47.5, 79.5)]


def test_cell_targets_of_hand_placed_points():
    frame, kp2d, kp3d = labelled_frame(cell_keypoints((100, 80), 32).uv)
    inside, target = cell_targets(frame, kp2d, kp3d, 32)
    assert inside.tolist() == [True, True, True, False, False, True]
    assert target.tolist() == [5, 0, 11, -1, -1, 6]  # the cell centres are keypoints 0..11, row-major


def test_cell_targets_take_the_keypoint_nearest_the_cell_centre_and_none_in_an_empty_cell():
    # cell 5 (centre 47.5, 47.5) holds pixels 1 and 2, pixel 2 nearer its centre; cell 0 holds none; cell 11 pixel 0
    uv = [[98, 78], [34, 60], [50, 45], [64, 33]]
    frame, kp2d, kp3d = labelled_frame(uv)
    _, target = cell_targets(frame, kp2d, kp3d, 32)
    assert target.tolist() == [2, -1, 0, -1, -1, 3]
    table = keypoint_of_cell(np.array(uv, float), (100, 80), 32)
    assert table[0] == -1 and table[1 + 5] == 2 and table[1 + 6] == 3 and (table == -1).sum() == 1 + 12 - 3


def test_matches_pair_inside_points_with_their_most_likely_cell():
    """logits by hand: points 0 and 2 inside (sigmoid 2 = 0.881, sigmoid 0.5 = 0.622 > 0.5), point 1 not
    (sigmoid -1 = 0.269); point 0's best cell 2 (softmax of (0, 0, ln 3) = 0.6), point 2's best cell 0 (0.5)."""
    classifier = DeepI2PClassifier(TINY["matcher"]).eval()
    logits = torch.tensor([[2.0, -1.0, 0.5]])
    cells = torch.tensor([[[0.0, 0.0, math.log(3)], [5.0, 0.0, 0.0], [math.log(2), 0.0, 0.0]]])
    classifier.forward = lambda d3, cell_xy: (logits, cells)
    frame, kp2d, _ = tiny_cells()
    kp3d = Keypoints3D.from_index(frame, np.arange(3))
    matches = classifier(frame, Keypoints2D(kp2d.uv[:3]), kp3d, Features(None, torch.zeros(3, D)))
    sigmoid = 1 / (1 + np.exp(-np.array([2.0, -1.0, 0.5])))
    assert matches.index3d.tolist() == [0, 2] and matches.index2d.tolist() == [2, 0]
    np.testing.assert_allclose(matches.score, [sigmoid[0] * 0.6, sigmoid[2] * 0.5], rtol=1e-6)
    np.testing.assert_allclose(matches.frustum, sigmoid, rtol=1e-6)
    assert matches.frustum.dtype == np.float32


def test_the_fusion_changes_the_points_only():
    frame, kp2d, kp3d = tiny_cells()
    stages = tiny_modules()
    with torch.no_grad():
        raw = Features(stages["encoder2d"](frame, kp2d), stages["encoder3d"](frame, kp3d))
        fused = stages["exchanger"](frame, kp2d, kp3d, raw)
        moved = stages["exchanger"](frame, Keypoints2D(kp2d.uv[:5]), kp3d, Features(raw.desc2d[:5], raw.desc3d))
    assert torch.equal(fused.desc2d, raw.desc2d) and fused.desc3d.shape == raw.desc3d.shape
    assert (fused.desc3d - raw.desc3d).abs().max() > 1e-3  # the image reached the points ...
    assert (moved.desc3d - fused.desc3d).abs().max() > 1e-4  # ... and which cells it has matters


def test_stages_refuse_another_cell_size_or_width():
    classifier = DeepI2PClassifier(TINY["matcher"])
    reason = classifier.check_compatible({"extractor2d": CellCentresExtractor({"cell_px": 32})})
    assert reason == "matcher 'deepi2p-classifier' has cell_px 16 but extractor2d 'deepi2p-cell-centres' has cell_px 32"
    fusion = DeepI2PFusion({**TINY["exchanger"], "descriptor_dim": D + 8})
    assert "descriptor_dim 48 but exchanger 'deepi2p-fusion' has descriptor_dim 56" in classifier.check_compatible(
        {"exchanger": fusion}
    )


def test_the_frustum_solver_needs_scores_and_a_known_variant():
    frame, kp2d, kp3d = tiny_cells()
    estimate = FrustumSolver()(frame, kp2d, kp3d, Matches.empty())
    assert not estimate.ok and "carry no frustum scores" in estimate.message
    with pytest.raises(ValueError, match="variant must be '2d' or '3d'"):
        FrustumSolver({"variant": "4d"})


@pytest.mark.parametrize("size", ["PAPER", "CPU"])
def test_the_method_s_configs_build_and_agree(size):
    conf = getattr(configs, size)
    upstream = {"extractor2d": CellCentresExtractor()}
    upstream |= {kind: cls(conf[kind]) for kind, cls in zip(KINDS[:3], CLASSES[:3], strict=True)}
    assert DeepI2PClassifier(conf["matcher"]).check_compatible(upstream) is None
    assert upstream["exchanger"].check_compatible(upstream) is None


def test_the_cpu_size_classifies_points_in_their_yaw_canonical_frame():
    """The CPU size's point features do not move with the protocol's yaw and shift (the paper's size learns that)."""
    frame, _, kp3d = tiny_frame()
    encoder = DeepI2PPointEncoder({**TINY["encoder3d"], "canonical_yaw": configs.CPU["encoder3d"]["canonical_yaw"]})
    c, s = math.cos(2.0), math.sin(2.0)
    moved = frame.points.copy()
    moved[:, :3] = frame.points[:, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32).T + [7.0, -3.0, 0]
    moved_frame = dataclasses.replace(frame, points=moved)
    with torch.no_grad():
        before = encoder(frame, kp3d)
        after = encoder(moved_frame, Keypoints3D.from_index(moved_frame, kp3d.index))
    torch.testing.assert_close(after, before, atol=2e-4, rtol=1e-3)
    assert not DeepI2PPointEncoder({**TINY["encoder3d"]}).conf["canonical_yaw"]  # the paper's size: off


# --- training


def test_every_parameter_gets_a_gradient_from_the_loss():
    frame, kp2d, kp3d = tiny_cells()
    stages = tiny_modules()
    loss, terms = stages["matcher"].loss(frame, kp2d, kp3d, features_of(stages, frame, kp2d, kp3d))
    assert set(terms) == {"frustum", "cell", "inside"} and 0.2 < terms["inside"] < 0.9
    loss.backward()
    dead = [
        f"{k}.{n}" for k, m in stages.items() for n, p in m.named_parameters() if p.grad is None or not p.grad.any()
    ]
    assert dead == []


def test_the_loss_of_an_untrained_head_is_about_chance():
    """a zero head: every frustum logit 0 (BCE ln 2) and all 24 cells equally likely (cross-entropy ln 24)."""
    frame, kp2d, kp3d = tiny_cells()
    classifier = DeepI2PClassifier(TINY["matcher"])
    for module in (classifier.frustum_head, classifier.cell_weights[-1]):
        torch.nn.init.zeros_(module.weight)
        torch.nn.init.zeros_(module.bias)
    loss, terms = classifier.loss(frame, kp2d, kp3d, Features(None, torch.randn(len(kp3d), D)))
    assert terms["frustum"] == pytest.approx(math.log(2), rel=1e-6)
    assert terms["cell"] == pytest.approx(math.log(24), rel=1e-6)
    assert loss.item() == pytest.approx(math.log(2) + math.log(24), rel=1e-6)


def test_the_loss_falls_when_training_on_one_frame():
    frame, kp2d, kp3d = tiny_cells()
    stages = tiny_modules()
    optimiser = torch.optim.Adam([p for m in stages.values() for p in m.parameters()], lr=3e-3)
    history = []
    for _ in range(50):
        loss, terms = stages["matcher"].loss(frame, kp2d, kp3d, features_of(stages, frame, kp2d, kp3d))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        history.append((loss.item(), terms["frustum"], terms["cell"]))
    (first, frustum0, cell0), (last, frustum1, cell1) = history[0], history[-1]
    # measured when written: total 3.96 -> 2.34, frustum 0.62 -> 0.37 (84% of the points are inside: the prior's
    # entropy is 0.44), cell 3.35 -> 1.97 (chance: ln 24 = 3.18)
    assert last < 0.75 * first and frustum1 < 0.75 * frustum0 and cell1 < 0.75 * cell0


def sample(stages, seed: int, cut: int = 0) -> dict:
    """a tiny frame's prepared sample; `cut` drops that many 2D and 3D keypoints, so two samples differ in size."""
    frame, kp2d, kp3d = tiny_cells(seed)
    if cut:
        kp2d = Keypoints2D(kp2d.uv[:-cut])
        kp3d = Keypoints3D.from_index(frame, kp3d.index[: -5 * cut])
    inputs = {k: prepare_stage(k, stages[k], frame, kp2d, kp3d, {}) for k in KINDS}
    return {"inputs": inputs, "n2d": len(kp2d), "n3d": len(kp3d)}


def loss_and_grads(stages, samples):
    for module in stages.values():
        module.zero_grad(set_to_none=True)
    loss, terms = BatchForward(stages)(collate_samples(samples))
    loss.backward()
    return (
        loss.detach(),
        terms,
        {f"{k}.{n}": p.grad.clone() for k, m in stages.items() for n, p in m.named_parameters()},
    )


def test_a_batch_of_two_gives_the_mean_loss_and_gradients_of_its_frames():
    stages = tiny_modules()
    a, b = sample(stages, 0), sample(stages, 3, cut=4)
    assert (a["n2d"], a["n3d"]) != (b["n2d"], b["n3d"])  # different counts: the batch pads one of them
    loss_a, terms_a, grads_a = loss_and_grads(stages, [a])
    loss_b, terms_b, grads_b = loss_and_grads(stages, [b])
    loss_ab, terms_ab, grads_ab = loss_and_grads(stages, [a, b])
    torch.testing.assert_close(loss_ab, (loss_a + loss_b) / 2, atol=1e-5, rtol=1e-5)
    for key in ("frustum", "cell", "inside"):
        assert terms_ab[key] == pytest.approx((terms_a[key] + terms_b[key]) / 2, rel=1e-5)
    assert_mean_of_frames(grads_ab, grads_a, grads_b)


def test_the_per_frame_loss_is_the_batch_of_one():
    frame, kp2d, kp3d = tiny_cells()
    stages = tiny_modules()
    with torch.no_grad():
        alone, _ = stages["matcher"].loss(frame, kp2d, kp3d, features_of(stages, frame, kp2d, kp3d))
        batched, _ = BatchForward(stages)(collate_samples([sample(stages, 0)]))
    torch.testing.assert_close(alone, batched, atol=1e-5, rtol=1e-5)


# --- the method


def test_the_method_declares_its_sizes_and_presets(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "classic,deepi2p")
    registry = build_registry(strict=True)
    method = registry.method("deepi2p")
    assert [s.name for s in method.sizes] == ["paper", "cpu-size", "official"]
    assert [w.name for w in method.weights] == ["deepi2p-cpu-synthetic.pt"]  # the shipped CPU-size checkpoint
    cpu, paper = (expand(base_combinations(registry, p), {}, None, registry)[0] for p in ("deepi2p", "deepi2p-paper"))
    auto = [job.weights for job in prepare(registry, [cpu, paper])]
    assert auto[0].startswith("deepi2p-cpu-synthetic@") and auto[1] == "untrained"  # --weights auto, by size
    owned = {name for name, preset in registry.presets.items() if preset.method == "deepi2p"}
    assert owned == {"deepi2p", "deepi2p-paper", "deepi2p-official", "deepi2p-frustum-2d", "deepi2p-frustum-3d"}
    (pnp,) = registry.presets["deepi2p"].combinations
    assert pnp["variant"] == "cpu-size" and pnp["solver"] == "epnp-ransac" and pnp["encoder2d"] == "deepi2p-resnet"
    assert pnp["confs"]["solver"] == {"reprojection_error_px": 0.6 * 64}  # the paper code's 0.6 cell
    assert pnp["confs"]["extractor3d"] == {"max_keypoints": configs.CPU_POINTS}
    (planar,) = registry.presets["deepi2p-frustum-2d"].combinations
    assert planar["solver"] == "deepi2p-frustum" and "solver" not in planar["confs"]  # the solver's default: 2d
    (full,) = registry.presets["deepi2p-frustum-3d"].combinations
    assert full["confs"]["solver"] == {"variant": "3d"} and full["variant"] == "cpu-size, 3d"
    assert {k: v for k, v in full["confs"].items() if k != "solver"} == planar["confs"]
    (paper,) = registry.presets["deepi2p-paper"].combinations
    assert paper["variant"] == "" and paper["confs"]["extractor3d"] == {"max_keypoints": 20480}


def test_listing_the_plugin_imports_no_torch():
    code = "import sys, i2pbench_deepi2p.plugin as p; p.deepi2p(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
