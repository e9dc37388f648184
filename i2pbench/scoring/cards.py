"""Protocol cards: each paper's test inputs and scoring rules, named and versioned, with the code lines they follow.

A card states what its paper's stages were given (`Inputs`, per dataset family) and how its evaluation script scores
poses (`ScoringRules`). `edgeregnet` is i2pbench's own protocol, the default: its `Protocol` is the card every run
had before cards existed, so its identity and cache keys never moved. Built-in cards are registered like any
plugin's, through `register_protocols` (the built-in `datasets` plugin registers them); a third party adds its own
with `register(ProtocolCard(...))`. A card's `version` goes up whenever its inputs or rules change, and a non-default
card's name and version are part of the run's protocol identity, hence of every cache key.

Line numbers cite the peers' repositories at the commits in SOURCES; docs/protocol.md explains each card.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..errors import PluginError
from .rules import ScoringRules

if TYPE_CHECKING:  # cards are registered by `i2pbench plugins` too, which must import neither numpy nor pandas
    from .protocol import Protocol

DEFAULT_NAME, DEFAULT_VERSION = "edgeregnet", 1  # as i2pbench.scoring.protocol's (a test checks they agree)

TAU = 2 * math.pi
SOURCES = {  # repository -> the commit every line number below refers to
    "ESRSchao/EdgeRegNet": "bfcf3f8527a1f9368bdd8e4e977068f2e188626b",
    "rsy6318/CorrI2P": "4f4a7550543ed4fb0e77dff9b0aecad0e42ad227",
    "lijx10/DeepI2P": "cd21389db9ddcccfd2cea306e54342562681b20f",
    "junshengzhou/VP2P-Match": "be76104fd6aa33d25aaa5023ad28adfb271f0d44",
    "WHU-USI3DV/CoFiI2P": "ed90edf51cca540ee76152d91133c7e79b63256c",
    "OpenSpaceAI/ICL-I2PReg": "0bf404091b8e4a8b9bb5e199416d91e7e7d1ae4f",
}


@dataclass(frozen=True)
class Inputs:
    """What the stages are given on one dataset family."""

    image_top: int = 0  # rows cut off the image's top first
    image_scale: float = 1.0  # then the image resized by this factor (K scaled with it)
    image_crop: tuple[int, int] | None = None  # then centre-cropped to (H, W); None: the whole image
    points: int | None = None  # points sampled from the scan; None: every point the dataset delivers
    voxel_m: float | None = None  # voxel-grid downsampling before sampling; None: none
    sweeps: int = 1  # sweeps accumulated into one scan; 1: the frame's own sweep alone
    other_frame: bool = False  # the image is another frame's (DeepI2P: up to 10 m away), not the scan's own
    pose_frame: str = "lidar"  # the frame the random transform acts in: lidar (yaw about z, t on x, y) or camera
    rotation_range_rad: float = TAU  # yaw ~ U[-r, r]
    translation_range_m: float = 10.0  # each horizontal translation ~ U[-t, t]; 0 on the vertical axis

    def describe(self) -> dict[str, str]:
        """Each input in words, for the differences a refusal lists."""
        top = f"top {self.image_top} rows cut, " if self.image_top else ""
        crop = "" if self.image_crop is None else f", centre crop {self.image_crop[0]} x {self.image_crop[1]}"
        full = self.image_scale == 1.0 and self.image_crop is None and not self.image_top
        return {
            "image": "full resolution" if full else f"{top}resized x{self.image_scale:g}{crop}",
            "frame": "another frame's image, up to 10 m away" if self.other_frame else "the scan's own frame",
            "points": "the whole scan" if self.points is None else f"{self.points} sampled",
            "voxel": "none" if self.voxel_m is None else f"{self.voxel_m:g} m grid",
            "sweeps": "the frame's sweep" if self.sweeps == 1 else f"{self.sweeps} sweeps accumulated",
            "pose": f"{self.pose_frame} frame: yaw U[±{math.degrees(self.rotation_range_rad):g}°], horizontal "
            f"t U[±{self.translation_range_m:g} m]",
        }

    def differences(self, other: Inputs, label: str = "i2pbench") -> list[str]:
        """'what: this (label: other's)' for every input that differs."""
        mine, theirs = self.describe(), other.describe()
        return [f"{key}: {mine[key]} ({label}: {theirs[key]})" for key in mine if mine[key] != theirs[key]]


# the peers' preprocessed nuScenes layouts (i2pbench.data.peer_nuscenes) and the card whose loader reads each
NUSCENES_LAYOUTS = {"cofii2p-nuscenes": "cofii2p", "corri2p-nuscenes": "corri2p"}
NATIVE = Inputs()  # the dataset's frame as it is: the default card's inputs


def unsupported(inputs: Inputs) -> list[str]:
    """The inputs i2pbench cannot make yet (Protocol.apply makes the image cut, resize and crop, the voxel grid,
    the point sampling and camera-frame poses; not accumulated sweeps or another frame's image)."""
    described = inputs.describe()
    return [f"{key}: {described[key]} (i2pbench: {NATIVE.describe()[key]})" for key, needed in
            (("sweeps", inputs.sweeps != 1), ("frame", inputs.other_frame)) if needed]  # fmt: skip


@dataclass(frozen=True)
class ProtocolCard:
    """A paper's protocol: its inputs per dataset family, its scoring rules, and the code they were read from."""

    name: str
    version: int
    paper: str
    kitti: Inputs
    nuscenes: Inputs | None  # None: the paper's code has no nuScenes pipeline to follow
    rules: ScoringRules
    cites: tuple[str, ...]  # "repo path:lines — what", at the commit SOURCES names (or the card's own source)
    notes: tuple[str, ...] = ()  # where the card departs from the code, or the code is ambiguous

    def inputs(self, dataset: str) -> Inputs | None:
        """The card's inputs for a dataset: nuScenes' for a dataset named nuscenes* or a peer's nuScenes layout,
        KITTI's for any other (the synthetic streets mimic KITTI)."""
        return self.nuscenes if dataset.startswith("nuscenes") or dataset in NUSCENES_LAYOUTS else self.kitti

    def protocol(self, seed: int = 0, dataset: str = "kitti") -> Protocol:
        """The Protocol a run under this card uses on `dataset`: its inputs, its rules, its name and version."""
        from .protocol import Protocol

        i = self.inputs(dataset) or NATIVE
        crop = i.image_crop or (0, 0)
        return Protocol(
            seed=seed, rotation_range_rad=i.rotation_range_rad, translation_range_m=i.translation_range_m,
            rules=self.rules, name=self.name, version=self.version,
            image_top=i.image_top, image_scale=i.image_scale, image_crop_h=crop[0], image_crop_w=crop[1],
            points=i.points or 0, voxel_m=i.voxel_m or 0.0, pose_frame=i.pose_frame,
        )  # fmt: skip

    def unmet(self, dataset: str) -> list[str]:
        """The inputs i2pbench cannot give this card's stages on `dataset` ([] when a run can honour it)."""
        owner = NUSCENES_LAYOUTS.get(dataset)
        if owner == self.name:
            return []  # the export made the sweeps and the nearby camera's image; protocol_peer the rest
        if owner and self.name in NUSCENES_LAYOUTS.values():
            return [f"{dataset} holds the files {owner}'s loader reads (its image sizes, its clouds): run it under "
                    f"--protocol {owner}"]  # fmt: skip
        inputs = self.inputs(dataset)
        if inputs is None:
            return [f"{self.paper}'s code has no {dataset} pipeline to follow"]
        return unsupported(inputs)


def _cite(repo: str, where: str) -> str:
    return f"{repo}@{SOURCES[repo][:8]} {where}"


EDGEREGNET = ProtocolCard(
    name=DEFAULT_NAME,
    version=DEFAULT_VERSION,
    paper="EdgeRegNet",
    kitti=NATIVE,
    nuscenes=NATIVE,
    rules=ScoringRules(),
    cites=(
        _cite("ESRSchao/EdgeRegNet", "test.py:131-135 — RRE = sum |xzy Euler| of inv(T_pred) @ T_gt, RTE its t"),
        _cite("ESRSchao/EdgeRegNet", "test.py:140-142 — a failed PnP is RRE = RTE = inf"),
        _cite("ESRSchao/EdgeRegNet", "test.py:40-45 — T_range ±10 m on x and y, 0 on z, a 2π angle"),
        _cite("ESRSchao/EdgeRegNet", "KITTI_bin.py:106-108 — the image pasted unscaled into 1250 x 376"),
    ),
    notes=(
        "test.py writes per-frame errors and no aggregate (l.147-151); Acc. (RRE < 5°, RTE < 2 m over all frames) "
        "and mean ± std over RRE < 10°, RTE < 5 m (ddof 0) follow the papers' tables, as i2pbench always has",
        "KITTI_bin.py never reads T_range: the test files hold precomputed poses, so the rotation's axis is the "
        "unreleased preprocessing's; i2pbench draws yaw about LiDAR z",
        "EdgeRegNet's preprocessed test files hold 20,480 points (KITTI_bin.py:112), by a script not released; "
        "i2pbench gives every point and lets the extractors cap keypoints",
    ),
)

LOADER_NOTE = (
    "v2: on KITTI (original or CorrI2P layout) each frame is built as the paper's preprocessing and loader build it "
    "for the frame's dataset index (i2pbench.scoring.protocol_peer, checked against the loaders: docs/datasets.md); v1 "
    "voxelised in the LiDAR frame and drew from i2pbench's per-frame generator"
)
_PEER_KITTI = Inputs(image_scale=0.5, image_crop=(160, 512), points=40960, voxel_m=0.1, pose_frame="camera")
_PEER_NUSCENES = Inputs(image_top=100, image_scale=0.4, image_crop=(160, 320), points=40960, voxel_m=0.1, sweeps=3,
                        pose_frame="camera")  # fmt: skip

CORRI2P = ProtocolCard(
    name="corri2p",
    version=2,
    paper="CorrI2P",
    kitti=_PEER_KITTI,
    nuscenes=dataclasses.replace(_PEER_NUSCENES, image_scale=0.2),
    rules=ScoringRules(failure="identity", filter_rre_deg=math.inf, filter_rte_m=math.inf),
    cites=(
        _cite("rsy6318/CorrI2P", "cal_error_all.py:9-16 — RRE = sum |xzy Euler| of inv(P_pred) @ P_gt"),
        _cite("rsy6318/CorrI2P", "cal_error_all.py:81-103 — solvePnPRansac's retval ignored: its pose is scored"),
        _cite("rsy6318/CorrI2P", "analysis.py:78-79 — mean and np.std (ddof 0) over every frame"),
        _cite("rsy6318/CorrI2P", "analysis.py:81-86 — the outlier filter commented out"),
        _cite("rsy6318/CorrI2P", "analysis.py:89-91 — success RRE < 5 and RTE < 2 over every frame"),
        _cite("rsy6318/CorrI2P", "kitti_pc_img_dataloader.py:269-287 — 0.1 m voxels, 40960 points, x0.5, centre crop"),
        _cite("rsy6318/CorrI2P", "kitti_pc_img_dataloader.py:259-263 — the cloud taken into the camera frame first"),
        _cite("rsy6318/CorrI2P", "eval_all.py:25,34-45 — 40960 points; camera-frame t_x, t_z ±10 m, yaw ±2π"),
        _cite(
            "rsy6318/CorrI2P",
            "nuScenes/options.py:15-16,21-24,30 — 3 sweeps, top 100 rows, x0.2, 160 x 320, 40960 points",
        ),
        _cite("rsy6318/CorrI2P", "nuScenes_script/make_dataset.py:263-264 — the top rows cut before saving"),
    ),
    notes=(
        "a failed PnP returns uninitialised rvec/tvec that cal_error_all.py scores as they are; the card scores "
        "the identity pose instead (what DeepI2P substitutes on purpose), a finite, reproducible stand-in",
        LOADER_NOTE,
        "kitti_pc_img_dataloader.py seeds nothing at test; i2pbench seeds each index as CoFiI2P does",
    ),
)

VP2P_MATCH = ProtocolCard(
    name="vp2p-match",
    version=1,
    paper="VP2P-Match",
    kitti=_PEER_KITTI,
    nuscenes=None,
    rules=ScoringRules(failure="identity", filter_rre_deg=math.inf, filter_rte_m=math.inf),
    cites=(
        _cite("junshengzhou/VP2P-Match", "run_kitti.py:17-23 — RRE = sum |xzy Euler| of inv(P_pred) @ P_gt"),
        _cite("junshengzhou/VP2P-Match", "run_kitti.py:89-101 — solvePnPRansac's retval ignored"),
        _cite("junshengzhou/VP2P-Match", "run_kitti.py:116-119 — (r < 5) & (t < 2) over every frame; np.std"),
        _cite("junshengzhou/VP2P-Match", "models/kitti_dataset.py:306-319 — 0.1 m voxels, sampling, x0.5, centre crop"),
        _cite("junshengzhou/VP2P-Match", "utils/options.py:11-23,34-39 — 160 x 512, 40960 points, t ±10 m, yaw ±2π"),
    ),
    notes=(
        "the same rules as CorrI2P's; a failed PnP is scored as the identity pose (see corri2p)",
        "the repository has no nuScenes loader at this commit, so the card has no nuScenes inputs",
    ),
)

DEEPI2P = ProtocolCard(
    name="deepi2p",
    version=1,
    paper="DeepI2P",
    kitti=Inputs(
        image_top=50,
        image_scale=0.5,
        image_crop=(160, 512),
        points=20480,
        sweeps=3,
        other_frame=True,
        pose_frame="camera",
        rotation_range_rad=0.0,
        translation_range_m=0.0,
    ),  # fmt: skip
    nuscenes=Inputs(
        image_top=100,
        image_scale=0.2,
        image_crop=(160, 320),
        points=20480,
        sweeps=3,
        other_frame=True,
        rotation_range_rad=0.0,
        translation_range_m=0.0,
    ),  # fmt: skip
    rules=ScoringRules(
        failure="identity",
        max_translation_m=14.14,
        drop_all_inliers=True,
        filter_rre_deg=math.inf,
        filter_rte_m=math.inf,
    ),
    cites=(
        _cite("lijx10/DeepI2P", "evaluation/registration_pnp.py:84-92 — RRE = sum |xzy Euler| of inv(P_pred) @ P_gt"),
        _cite("lijx10/DeepI2P", "evaluation/registration_pnp.py:123-146 — failure: identity pose, cost 1"),
        _cite("lijx10/DeepI2P", "evaluation/registration_pnp.py:134 — an estimate with ||t|| >= 14.14 m: identity"),
        _cite("lijx10/DeepI2P", "evaluation/registration_result_analysis.py:22-25 — frames with cost <= 1e-6 left out"),
        _cite("lijx10/DeepI2P", "evaluation/registration_result_analysis.py:37-41 — t < 2 & r < 5; sqrt(np.var)"),
        _cite(
            "lijx10/DeepI2P",
            "data/kitti_pc_img_pose_loader.py:294-306 — 3 sweeps; 0.3 m voxels past 2N points; 20480 sampled",
        ),
        _cite(
            "lijx10/DeepI2P",
            "data/kitti_pc_img_pose_loader.py:318-349 — frame j's image, top 50 rows cut, x0.5, centre crop",
        ),
        _cite("lijx10/DeepI2P", "data/kitti_pc_img_pose_loader.py:366-372 — at test ('val') no random transform"),
        _cite("lijx10/DeepI2P", "kitti/options.py:15-28 — 3 sweeps, 10 m / 40 frames to frame j, 160 x 512, 20480"),
        _cite(
            "lijx10/DeepI2P",
            "data/nuscenes_pc_img_pose_loader.py:297-322,339-345 — a nearby camera record, top "
            "rows cut, x0.2, centre crop; no random transform at test",
        ),
        _cite("lijx10/DeepI2P", "nuscenes_t/options.py:15-28 — 3 sweeps, 100 rows, x0.2, 160 x 320, 20480 points"),
    ),
    notes=(
        "the cost is registration_pnp.py's outlier ratio 1 - inliers / matches; the card leaves out a solved frame "
        "whose every match is a RANSAC inlier (n_inliers == n_matches), the only way the ratio is <= 1e-6",
        "at test the pose to find is the real motion between the accumulated scan and an image taken up to 10 m "
        "away, with no random transform (lijx10/DeepI2P#7; the 'val_random_Ry' mode adds a yaw); i2pbench cannot "
        "pair a scan with another frame's image yet",
        "a 0.3 m voxel grid applies only to a cloud over 2 x 20480 points, which the card does not model",
    ),
)

COFII2P = ProtocolCard(
    name="cofii2p",
    version=2,
    paper="CoFiI2P",
    kitti=dataclasses.replace(_PEER_KITTI, points=20480),
    nuscenes=dataclasses.replace(_PEER_NUSCENES, points=20480),
    rules=ScoringRules(failure="skip", acc_rre_deg=10.0, acc_rte_m=5.0),
    cites=(
        _cite("WHU-USI3DV/CoFiI2P", "evaluation/eval_all.py:16-22 — RRE = sum |xzy Euler| of inv(P_pred) @ P_gt"),
        _cite("WHU-USI3DV/CoFiI2P", "evaluation/eval_all.py:107-117 — a failed PnP is never recorded"),
        _cite("WHU-USI3DV/CoFiI2P", "evaluation/calc_result.py:3-13 — rate over recorded frames; mean, std of passes"),
        _cite("WHU-USI3DV/CoFiI2P", "evaluation/calc_result.py:28-29,33 — the (10°, 5 m) thresholds"),
        _cite("WHU-USI3DV/CoFiI2P", "data/options.py:12-21,33-38 — 160 x 512, 20480 points, t ±10 m, yaw ±2π"),
        _cite("WHU-USI3DV/CoFiI2P", "data/kitti.py:283-320 — 0.1 m voxels, sampling, x0.5, centre crop"),
        _cite("WHU-USI3DV/CoFiI2P", "data/kitti.py:261-264 — numpy and Python seeded with SeedSequence([index])"),
        _cite("WHU-USI3DV/CoFiI2P", "data/options.py:68-74 — nuScenes: 3 sweeps, top 100 rows, x0.4, 160 x 320"),
        _cite("WHU-USI3DV/CoFiI2P", "data/build_nuscenes/build_dataset.py:253-254 — the top rows cut before saving"),
    ),
    notes=(
        "calc_result.py prints three threshold pairs, (1e5, 1e5), (45°, 10 m) and (10°, 5 m); the card takes "
        "(10°, 5 m), the pair whose mean ± std the paper reports, for both the rate and the filter",
        "the rate divides by PnP successes, not by frames: a failure leaves the denominator",
        LOADER_NOTE,
    ),
)

ICL = ProtocolCard(
    name="icl",
    version=1,
    paper="ICL (ICL-I2PReg)",
    kitti=_PEER_KITTI,
    nuscenes=None,
    rules=ScoringRules(rre="yaw-2d", rte="t-diff", failure="identity", filter_rre_deg=math.inf, filter_rte_m=math.inf),
    cites=(
        _cite(
            "OpenSpaceAI/ICL-I2PReg",
            "kitti/stage_2/loss.py:165-175 — RRE the angle of (R[2,0], R[0,0]); RTE = ||t_gt - t_est||",
        ),
        _cite("OpenSpaceAI/ICL-I2PReg", "vision3d-main/vision3d/utils/opencv.py:36-38,49 — retval ignored"),
        _cite("OpenSpaceAI/ICL-I2PReg", "kitti/stage_2/eval_RRE_RTE_pnp.py:24-35 — mean, np.std, RTE<2 & RRE<5"),
        _cite("OpenSpaceAI/ICL-I2PReg", "kitti/stage_2/config.py:45 — 40960 points"),
        _cite(
            "OpenSpaceAI/ICL-I2PReg",
            "vision3d-main/vision3d/datasets/registration/kitti_odometry/"
            "kitti_odometry.py:87-88,95-96,271-289 — t ±10 m, yaw ±2π, 160 x 512, 0.1 m voxels, x0.5, centre crop",
        ),
    ),
    notes=(
        "the RRE reads only yaw: a pure pitch or roll error scores 0°",
        "fewer than 4 matches returns None and the script crashes; a failed PnP is scored as the identity pose",
    ),
)

BUILTIN: tuple[ProtocolCard, ...] = (EDGEREGNET, CORRI2P, DEEPI2P, VP2P_MATCH, COFII2P, ICL)


def check(card: object, plugin: str) -> ProtocolCard:
    """A plugin's registration, refused (naming the plugin) unless it is a ProtocolCard with a name and version."""
    if not isinstance(card, ProtocolCard):
        raise PluginError(f"plugin {plugin!r} registered {card!r} as a protocol, but it is no "
                          "i2pbench.scoring.cards.ProtocolCard")  # fmt: skip
    if not card.name or not isinstance(card.version, int) or card.version < 1:
        raise PluginError(f"plugin {plugin!r}: protocol {card.name!r} needs a name and a version >= 1")
    return card


def label(protocol: Protocol) -> str:
    """'name vN', the protocol column of a leaderboard row."""
    return f"{protocol.name} v{protocol.version}"
