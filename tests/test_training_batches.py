"""Batched training of EdgeRegNet's stages: a padded batch is the mean of its frames, padding changes nothing."""

import numpy as np
import torch
from test_edgeregnet_training import TINY, one_thread, tiny_frame, tiny_modules  # noqa: F401 (an autouse fixture)

from i2pbench.api import Keypoints2D, Keypoints3D
from i2pbench.batching import BatchForward, collate, length_mask, pad_stack, prepare_stage
from i2pbench.training_data import collate_samples

KINDS = ("encoder2d", "encoder3d", "exchanger", "matcher")


def sample(stages, seed, cut=0):
    """a tiny frame's prepared sample; `cut` drops that many 2D and 3D keypoints (the random 2D ones and the last
    3D ones), so two samples differ in size."""
    frame, kp2d, kp3d = tiny_frame(seed)
    if cut:
        kp2d = Keypoints2D(kp2d.uv[:-cut])
        kp3d = Keypoints3D.from_index(frame, kp3d.index[:-cut])
    inputs = {k: prepare_stage(k, stages[k], frame, kp2d, kp3d, {}) for k in KINDS}
    return {"inputs": inputs, "n2d": len(kp2d), "n3d": len(kp3d)}


def loss_and_grads(stages, samples):
    for module in stages.values():
        module.zero_grad(set_to_none=True)
    loss, terms = BatchForward(stages)(collate_samples(samples))
    loss.backward()
    grads = {f"{k}.{n}": p.grad.clone() for k, m in stages.items() for n, p in m.named_parameters()}
    return loss.detach(), terms, grads


def test_pad_stack_pads_every_dim_at_the_end():
    out = pad_stack([torch.ones(1, 2), torch.full((2, 1), 2.0)], value=-1)
    assert out.tolist() == [[[1, 1], [-1, -1]], [[2, -1], [2, -1]]]
    assert length_mask(torch.tensor([2, 0]), 3).tolist() == [[True, True, False], [False, False, False]]


def test_a_batch_of_two_gives_the_mean_loss_and_gradients_of_its_frames():
    stages = dict(zip(KINDS, tiny_modules(), strict=True))
    a, b = sample(stages, 0), sample(stages, 3, cut=20)
    assert (a["n2d"], a["n3d"]) != (b["n2d"], b["n3d"])  # different counts: the batch pads one of them
    loss_a, terms_a, grads_a = loss_and_grads(stages, [a])
    loss_b, terms_b, grads_b = loss_and_grads(stages, [b])
    loss_ab, terms_ab, grads_ab = loss_and_grads(stages, [a, b])
    assert terms_a["pairs"] >= 20 and terms_b["pairs"] >= 20
    # same operations on the same numbers, up to float summation order (measured: 1e-6 on the loss, and the
    # gradients within 2.4% of their tolerance, at 1 and 2 threads)
    torch.testing.assert_close(loss_ab, (loss_a + loss_b) / 2, atol=1e-5, rtol=1e-5)
    assert terms_ab["pairs"] == (terms_a["pairs"] + terms_b["pairs"]) / 2
    for name, grad in grads_ab.items():
        torch.testing.assert_close(grad, (grads_a[name] + grads_b[name]) / 2, atol=1e-5, rtol=1e-4, msg=name)


def test_padded_keypoints_change_nothing():
    """a frame's descriptors next to a larger frame (its keypoints padded) equal its descriptors alone."""
    stages = dict(zip(KINDS, tiny_modules(), strict=True))
    for module in stages.values():
        module.eval()
    small, large = sample(stages, 3, cut=20), sample(stages, 0)
    features = []
    for items in ([small], [small, large]):
        batch = collate_samples(items)
        inputs, (m2, m3) = batch["inputs"], batch["masks"]
        with torch.no_grad():
            d2 = torch.nn.Module.__call__(stages["encoder2d"], inputs["encoder2d"])
            d3 = torch.nn.Module.__call__(stages["encoder3d"], inputs["encoder3d"])
            d2, d3 = torch.nn.Module.__call__(stages["exchanger"], inputs["exchanger"], d2, d3, m2, m3)
        features.append((d2[0, : small["n2d"]], d3[0, : small["n3d"]]))
    assert not bool(collate_samples([small, large])["masks"][0][0].all())  # the small frame really was padded
    for alone, padded in zip(*features, strict=True):
        # masked and unmasked SDPA take different kernels: measured 2.5e-6 apart; attending to the padding: 2.8e-2
        torch.testing.assert_close(padded, alone, atol=1e-4, rtol=0)


def test_collate_lists_what_is_not_a_tensor_and_drops_broken_samples():
    assert collate([{"a": torch.zeros(2), "b": "x"}, {"a": torch.ones(3), "b": "y"}])["b"] == ["x", "y"]
    batch = collate_samples([{"index": 4, "error": "DataError: bad.bin"}])
    assert batch["size"] == 0 and batch["errors"] == ["DataError: bad.bin"]


def test_the_cached_grouping_is_reused_across_transforms():
    """the per-frame cache keeps the PointNet++ grouping; a second prepare of a moved frame reuses it as is."""
    from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder

    frame, _, kp3d = tiny_frame()
    encoder = PointNet2Encoder(TINY["encoder3d"])
    cache: dict = {}
    first = {k: v.clone() for k, v in encoder.prepare(frame, kp3d, cache=cache).items()}
    assert set(cache["grouping"]) == {"fps1", "ball1", "fps2", "ball2", "up", "edge"}
    cache["grouping"]["fps1"][:] = 0  # a tampered cache shows it is read, not recomputed
    again = encoder.prepare(frame, kp3d, cache=cache)
    assert not torch.equal(first["fps1"], again["fps1"]) and int(again["fps1"].max()) == 0
    np.testing.assert_array_equal(first["xyz"].numpy(), again["xyz"].numpy())


def test_bf16_autocast_runs_on_the_cpu_and_keeps_the_loss_close_to_float32():
    stages = dict(zip(KINDS, tiny_modules(), strict=True))
    batch = collate_samples([sample(stages, 0), sample(stages, 3, cut=20)])
    with torch.no_grad():
        full, _ = BatchForward(stages)(batch)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            half, terms = BatchForward(stages)(batch)
    assert half.dtype == torch.float32 and torch.isfinite(half)  # the loss itself stays float32
    assert abs(half.item() - full.item()) < 0.05 * full.item()  # bf16 keeps ~3 digits; measured: 0.18%
    assert terms["pairs"] > 0


def test_only_the_matcher_s_prepare_sees_the_ground_truth():
    seen = {}

    class Spy:
        def __init__(self, kind):
            self.kind = kind

        def prepare(self, frame, *args, cache=None):
            seen[self.kind] = frame.T_gt is not None
            return {}

    frame, kp2d, kp3d = tiny_frame()
    for kind in KINDS:
        prepare_stage(kind, Spy(kind), frame, kp2d, kp3d, None)
    assert seen == {"encoder2d": False, "encoder3d": False, "exchanger": False, "matcher": True}
