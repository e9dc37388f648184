"""EdgeRegNet's modules through the stage interface on a tiny hand-built frame: shapes, gradients, overfitting."""

import numpy as np
import pytest
import torch
from i2pbench_edgeregnet.attention import AttentionExchanger
from i2pbench_edgeregnet.matching import OptimalMatcher
from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder
from i2pbench_edgeregnet.superpoint import SuperPointEncoder

from i2pbench.api import Features, Frame, Keypoints2D, Keypoints3D, Matches
from i2pbench.geometry.transforms import project

D = 32
TINY = {
    "encoder2d": {"descriptor_dim": D, "channels": (8, 8, 16, 16), "head_channels": 32},
    "encoder3d": {
        "descriptor_dim": D,
        "num_points": 1024,
        "sa1": {"npoint": 256, "radius": 0.1, "nsample": 8, "mlp": (16, 16)},
        "sa2": {"npoint": 64, "radius": 0.2, "nsample": 8, "mlp": (32, 32)},
        "fp_mlp": (32,),
        "head_mlp": (32,),
    },
    "exchanger": {"descriptor_dim": D, "num_blocks": 2, "num_heads": 4, "pe_mlp": (16,)},
    "matcher": {"descriptor_dim": D},
}


@pytest.fixture(autouse=True)
def one_thread():
    """tiny tensors run fastest on one thread, and two threads spin badly on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny_frame(seed: int = 0) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    """a 96 x 64 camera looking along LiDAR +x; 30 of 100 edge points have a 2D edge pixel half a pixel away."""
    rng = np.random.default_rng(seed)
    h, w, n = 64, 96, 2000
    K = np.array([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    xyz = np.c_[rng.uniform(2, 20, n), rng.uniform(-10, 10, n), rng.uniform(-2, 2, n)]
    points = np.c_[xyz, rng.uniform(0, 1, n)].astype(np.float32)
    image = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    frame = Frame("tiny", f"{seed}", image, points, np.zeros(n, np.int16), np.linalg.norm(xyz, axis=1), K, T)
    kp3d = Keypoints3D.from_index(frame, rng.choice(n, 100, replace=False))
    uv, front = project(K, T, kp3d.xyz.astype(np.float64))
    visible = uv[front & (uv[:, 0] > 1) & (uv[:, 0] < w - 2) & (uv[:, 1] > 1) & (uv[:, 1] < h - 2)][:30]
    kp2d = Keypoints2D(np.r_[visible + 0.5, rng.uniform(0, [w - 1, h - 1], (50, 2))].astype(np.float32))
    return frame, kp2d, kp3d


def tiny_modules() -> list[torch.nn.Module]:
    torch.manual_seed(0)
    return [
        SuperPointEncoder(TINY["encoder2d"]),
        PointNet2Encoder(TINY["encoder3d"]),
        AttentionExchanger(TINY["exchanger"]),
        OptimalMatcher(TINY["matcher"]),
    ]


def forward(modules, frame, kp2d, kp3d) -> Features:
    e2, e3, ex, _ = modules
    return ex(frame, kp2d, kp3d, Features(e2(frame, kp2d), e3(frame, kp3d)))


def test_shapes_through_the_stage_interface():
    frame, kp2d, kp3d = tiny_frame()
    e2, e3, ex, matcher = modules = tiny_modules()
    d2, d3 = e2(frame, kp2d), e3(frame, kp3d)
    assert d2.shape == (len(kp2d), D) and d3.shape == (len(kp3d), D)
    assert d2.dtype == d3.dtype == torch.float32
    torch.testing.assert_close(d2.norm(dim=1), torch.ones(len(kp2d)))  # L2-normalised by default
    features = forward(modules, frame, kp2d, kp3d)
    assert features.desc2d.shape == d2.shape and features.desc3d.shape == d3.shape
    matches = matcher(frame.without_ground_truth(), kp2d, kp3d, features)
    assert isinstance(matches, Matches) and matches.score.dtype == np.float32
    assert len(np.unique(matches.index2d)) == len(matches) == len(np.unique(matches.index3d))


def test_every_parameter_gets_a_gradient_from_the_loss():
    frame, kp2d, kp3d = tiny_frame()
    modules = tiny_modules()
    loss, terms = modules[-1].loss(frame, kp2d, kp3d, forward(modules, frame, kp2d, kp3d))
    assert terms["pairs"] >= 25 and set(terms) == {"fov", "sigma", "P", "pairs"}
    loss.backward()
    dead = [
        f"{type(m).__name__}.{name}"
        for m in modules
        for name, p in m.named_parameters()
        if p.grad is None or not p.grad.abs().sum() > 0
    ]
    assert dead == []


def test_one_frame_overfits():
    frame, kp2d, kp3d = tiny_frame()
    modules = tiny_modules()
    optimiser = torch.optim.Adam([p for m in modules for p in m.parameters()], lr=1e-3)
    losses = []
    for _ in range(100):
        loss, _ = modules[-1].loss(frame, kp2d, kp3d, forward(modules, frame, kp2d, kp3d))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    # the last steps spike now and then, and where depends on float rounding alone: under 14 choices of ATen, oneDNN
    # and MKL kernels (ATEN_CPU_CAPABILITY avx2/default, ONEDNN_MAX_CPU_ISA AVX2/SSE41, MKL_CBWR AVX2/COMPATIBLE
    # and mixes) the median of steps 91-100 went from 0.275 to 0.393 of the first loss (SSE41: 5 of the 10 spiked,
    # up to 8.3), the median of steps 81-100 from 0.294 to 0.324. Judge the latter; a quarter of the learning rate
    # gives 0.437, no training 1.0
    assert np.median(losses[-20:]) < 0.4 * losses[0]  # 12.3 -> 3.7 (median of steps 81-100) at ATen's AVX-512


def test_empty_keypoint_sets_give_no_match():
    frame, kp2d, kp3d = tiny_frame()
    e2, e3, ex, matcher = modules = tiny_modules()
    none2d, none3d = Keypoints2D(np.zeros((0, 2), np.float32)), Keypoints3D.from_index(frame, np.zeros(0, np.int64))
    with torch.inference_mode():
        assert e2(frame, none2d).shape == (0, D) and e3(frame, none3d).shape == (0, D)
        for a, b in ((none2d, kp3d), (kp2d, none3d)):
            assert len(matcher(frame, a, b, forward(modules, frame, a, b))) == 0


def test_partial_set_abstraction_override_keeps_the_other_defaults():
    encoder = PointNet2Encoder({"sa1": {"npoint": 100}})
    assert encoder.conf["sa1"] == {"npoint": 100, "radius": 0.1, "nsample": 32, "mlp": (64, 64, 128)}


@pytest.mark.parametrize("share", [False, True])
def test_shared_attention_weights_halve_the_blocks(share):
    blocks = AttentionExchanger({**TINY["exchanger"], "share_weights": share}).blocks
    per_block = sum(p.numel() for p in blocks[0].parameters())
    single = sum(p.numel() for p in blocks[0].self2d.parameters())
    assert per_block == (2 if share else 4) * single


def test_a_resized_image_gives_descriptors_for_every_pixel():
    frame, kp2d, _ = tiny_frame()
    encoder = SuperPointEncoder({**TINY["encoder2d"], "image_scale": 0.5})
    assert encoder(frame, kp2d).shape == (len(kp2d), D)


def moved_frames(mirror: bool = False) -> tuple[list[Frame], list[Keypoints3D]]:
    """a skewed scan and the same scan under a protocol-like transform (yaw 2.2 rad, planar shift), optionally also
    mirrored in y: a reflection no yaw-canonical frame can undo, the deliberately broken case."""
    from i2pbench.geometry.transforms import make_transform, rot_z

    frame, _, kp3d = tiny_frame()
    rng = np.random.default_rng(1)
    skewed = frame.points.copy()
    skewed[:, 0] = rng.exponential(8.0, len(skewed))  # a long tail ahead: a clear principal axis and moment sign
    T = make_transform(rot_z(2.2), np.array([-6.0, 9.0, 0.0]))
    if mirror:
        T = T @ np.diag([1.0, -1.0, 1.0, 1.0])
    moved = skewed.copy()
    moved[:, :3] = skewed[:, :3] @ T[:3, :3].T + T[:3, 3]
    frames = [Frame("tiny", "0", frame.image, p, frame.ring, frame.ranges, frame.K, None) for p in (skewed, moved)]
    return frames, [Keypoints3D.from_index(f, kp3d.index) for f in frames]


def descriptors_of_both(encoder: PointNet2Encoder, frames: list[Frame], kps: list[Keypoints3D]) -> list[torch.Tensor]:
    """both frames encoded with the first frame's grouping indices (FPS, balls, 3-NN).

    Those indices depend on distances alone, so they are the same under any rigid motion in exact arithmetic; in
    float, a neighbour at a ball's radius can flip with rounding on one machine and not another. Sharing them leaves
    only the continuous part of the encoder to compare, which rounding moves by ~1e-6.
    """
    cache: dict = {}
    with torch.no_grad():
        return [
            encoder.batched({k: v[None] for k, v in encoder.prepare(f, k, cache=cache).items()})[0]
            for f, k in zip(frames, kps, strict=True)
        ]


def test_with_the_canonical_frame_3d_descriptors_ignore_the_random_transform():
    frames, kps = moved_frames()
    _, kp2d, _ = tiny_frame()
    torch.manual_seed(0)
    encoder = PointNet2Encoder({**TINY["encoder3d"], "canonical_yaw": True}).eval()
    exchanger = AttentionExchanger({**TINY["exchanger"], "canonical_yaw": True}).eval()
    d2 = torch.nn.functional.normalize(torch.randn(len(kp2d), D), dim=-1)
    d3 = descriptors_of_both(encoder, frames, kps)
    with torch.no_grad():
        out = [exchanger(f, kp2d, k, Features(d2, d3[0])) for f, k in zip(frames, kps, strict=True)]
    torch.testing.assert_close(d3[1], d3[0], atol=1e-4, rtol=0)  # measured: 4e-7; broken: 0.44
    torch.testing.assert_close(out[1].desc3d, out[0].desc3d, atol=1e-4, rtol=0)
    torch.testing.assert_close(out[1].desc2d, out[0].desc2d, atol=1e-4, rtol=0)


def test_the_invariance_check_fails_when_the_invariance_is_lost():
    """the same comparison as above catches the paper's encoder (no canonical frame) and a mirrored scan."""
    torch.manual_seed(0)
    plain = PointNet2Encoder(TINY["encoder3d"]).eval()
    canonical = PointNet2Encoder({**TINY["encoder3d"], "canonical_yaw": True}).eval()
    for encoder, mirror in ((plain, False), (canonical, True)):
        d3 = descriptors_of_both(encoder, *moved_frames(mirror))
        assert (d3[1] - d3[0]).abs().max() > 1e-2
