"""The batched learned-stage contract (i2pbench.stages.learned.BatchedStage): a stage declares `prepare` and
`forward` (and `batch_loss` to train), and its per-frame call, its one-frame loss and its batched training all derive
from them."""

import numpy as np
import pytest
import torch
from torch import nn

from i2pbench.api import BatchedStage, Encoder2D, Exchanger, Features, Keypoints2D, Keypoints3D, Matcher, StageError
from i2pbench.testing import assert_conforms, synthetic_frame
from i2pbench.training.batching import BatchForward, collate, length_mask, prepare_stage


class Scale(BatchedStage, Encoder2D):
    """a toy encoder: each pixel's (u, v) times a learned 2 x 2 matrix."""

    name = "scale"
    default_conf = {"descriptor_dim": 2}  # D

    def __init__(self, conf=None):
        super().__init__(conf)
        self.linear = nn.Linear(2, 2, bias=False)
        nn.init.eye_(self.linear.weight)

    def prepare(self, frame, kp2d, device="cpu", cache=None):
        return {"uv": torch.from_numpy(np.asarray(kp2d.uv, np.float32)).to(device)}

    def forward(self, inputs):
        return self.linear(inputs["uv"])


class Shift(BatchedStage, Exchanger):
    """a toy exchanger: 2D descriptors plus the mean 3D descriptor of the frame (its real keypoints)."""

    name = "shift"
    default_conf = {"descriptor_dim": 2}  # D

    def __init__(self, conf=None):
        super().__init__(conf)
        self.gain = nn.Parameter(torch.ones(()))

    def prepare(self, frame, kp2d, kp3d, device="cpu", cache=None):
        return {"n3d": torch.tensor(len(kp3d), device=device)}

    def forward(self, inputs, d2, d3, mask2d=None, mask3d=None):
        mask3d = torch.ones(d3.shape[:2], dtype=torch.bool) if mask3d is None else mask3d
        mean = (d3 * mask3d[..., None]).sum(1) / inputs["n3d"][:, None]
        return d2 + self.gain * mean[:, None], d3


class Closest(BatchedStage, Matcher):
    """a toy trainable matcher whose loss is the mean squared 2D descriptor of each frame's real keypoints."""

    name = "closest"

    def __init__(self, conf=None):
        super().__init__(conf)
        self.weight = nn.Parameter(torch.ones(()))

    def prepare(self, frame, kp2d, kp3d, device="cpu", cache=None):
        return {"n2d": torch.tensor(len(kp2d), device=device)}

    def batch_loss(self, inputs, features, mask2d, mask3d):
        squares = (self.weight * features.desc2d).square().sum(-1) * mask2d
        per_frame = squares.sum(1) / inputs["n2d"]
        return per_frame.mean(), {"frames": float(len(per_frame))}


def keypoints(frame, n2d: int, n3d: int) -> tuple[Keypoints2D, Keypoints3D]:
    uv = np.stack([np.arange(n2d) * 3.0, np.arange(n2d) * 2.0], 1).astype(np.float32)
    return Keypoints2D(uv), Keypoints3D.from_index(frame, np.arange(n3d))


def test_the_per_frame_call_is_prepare_a_batch_of_one_and_forward_through_torch():
    frame = synthetic_frame()
    kp2d, _ = keypoints(frame, 4, 0)
    encoder = Scale()
    calls = []
    encoder.register_forward_hook(lambda module, args, out: calls.append(out.shape))
    with torch.no_grad():
        encoder.linear.weight.copy_(torch.tensor([[2.0, 0.0], [0.0, -1.0]]))
        out = encoder(frame, kp2d)
    assert calls == [torch.Size([1, 4, 2])]  # torch's module call ran forward once, on a batch of one
    np.testing.assert_array_equal(out.numpy(), kp2d.uv * np.array([2, -1], np.float32))
    assert out.dtype == torch.float32


def test_a_derived_exchanger_checks_its_inputs_and_passes_an_empty_side_through():
    frame = synthetic_frame()
    kp2d, kp3d = keypoints(frame, 3, 2)
    exchanger = Shift()
    d2, d3 = torch.zeros(3, 2), torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    out = exchanger(frame, kp2d, kp3d, Features(d2, d3))
    np.testing.assert_allclose(out.desc2d.detach().numpy(), [[2.0, 3.0]] * 3)  # + the mean 3D descriptor
    assert out.desc3d is not None and torch.equal(out.desc3d, d3)
    empty = Features(torch.zeros(0, 2), d3)
    assert exchanger(frame, keypoints(frame, 0, 2)[0], kp3d, empty) is empty
    with pytest.raises(StageError, match="needs descriptors on both sides"):
        exchanger(frame, kp2d, kp3d, Features(d2, None))
    with pytest.raises(StageError, match="expects 2-wide descriptors, got 3"):
        exchanger(frame, kp2d, kp3d, Features(torch.zeros(3, 3), d3))


def test_a_stage_declaring_only_prepare_and_forward_passes_the_conformance_kit():
    assert_conforms(Scale)


def test_the_one_frame_loss_is_batch_loss_on_a_batch_of_one():
    frame = synthetic_frame()
    kp2d, kp3d = keypoints(frame, 4, 3)
    features = Features(torch.tensor([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [0.0, 0.0]]), torch.zeros(3, 2))
    loss, terms = Closest().loss(frame, kp2d, kp3d, features)
    assert loss.item() == pytest.approx((1 + 4 + 2 + 0) / 4) and terms == {"frames": 1.0}


def test_batched_training_runs_the_contract_on_a_padded_batch():
    """two frames of 4 and 2 pixels: the batch's loss is the mean of the frames' own losses, padding unseen."""
    frame = synthetic_frame()
    stages = {"encoder2d": Scale(), "matcher": Closest()}
    frames = [(frame, *keypoints(frame, n2d, 3)) for n2d in (4, 2)]
    inputs = collate([{k: prepare_stage(k, s, *f, None) for k, s in stages.items()} for f in frames])
    masks = (length_mask(torch.tensor([4, 2]), 4), length_mask(torch.tensor([3, 3]), 3))
    loss, terms = BatchForward(stages)({"inputs": inputs, "masks": masks})
    alone = [
        stages["matcher"].loss(f, kp2d, kp3d, Features(stages["encoder2d"](f, kp2d), None))[0]
        for f, kp2d, kp3d in frames
    ]
    assert terms == {"frames": 2.0}
    torch.testing.assert_close(loss, torch.stack(alone).mean())
