"""The base of stages with parameters, and the contract of those that run on padded batches of frames.

Both subclass torch.nn.Module, so they are kept out of i2pbench.stages.components: importing the stage bases (to list
plugins, or to run the classic stages) must not import torch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import torch

from ..errors import StageError
from ..types import Features, Frame, Keypoints2D, Keypoints3D
from .components import Component

Device = torch.device | str  # where a stage's `prepare` puts its tensors


class LearnedComponent(Component, torch.nn.Module):
    """A component with parameters; its weights live in a checkpoint shared by the pipeline's learned stages.

    Its `__call__` is the stage's per-frame call (what the pipeline runs), so torch's module call, which runs
    `forward` with its hooks, is reached as `self.batched(...)`.
    """

    learned = True
    # config keys that only steer inference (score thresholds, filters): a checkpoint fits whatever their values, so
    # `--conf matcher.filter_threshold=0.2` can sweep them over shipped weights
    runtime_keys: ClassVar[frozenset[str]] = frozenset()
    # "network@sha8" of pretrained weights the stage starts from (not from the checkpoint), "" for none: on every
    # row it runs in (`Pipeline.weights_identity`), since those weights shape the results as much as the checkpoint
    pretrained_identity: str = ""

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        torch.nn.Module.__init__(self)
        Component.__init__(self, conf)

    __repr__ = Component.__repr__

    def compile_targets(self) -> list[torch.nn.Module]:
        """The fixed-shape submodules worth `torch.compile` (`train --compile`): none by default, since a stage's
        data-dependent loops (point sampling, say) would be unrolled or recompiled per input, not sped up."""
        return []

    @property
    def device(self) -> torch.device:
        """where the parameters are (the CPU for a stage without any)."""
        return next(self.parameters(), torch.empty(0)).device

    def batched(self, *args: Any) -> Any:
        """`forward(*args)` through torch's module call (forward hooks, compiled submodules): what `module(...)` is
        for a plain torch module, which a stage's per-frame `__call__` replaces."""
        return torch.nn.Module.__call__(self, *args)


class BatchedStage(LearnedComponent):
    """A learned stage that runs padded batches of frames: training takes several at once, and the per-frame call of a
    run is derived from the same code, a batch of one. It declares `prepare` and a batched `forward` (and, for a
    trainable matcher, `batch_loss`); docs/writing-a-plugin.md, section 12, spells the contract out.

    `forward` takes `prepare`d inputs collated into a batch (`batching.collate`: a leading B, tensors zero-padded at
    the end) and keypoint masks [B x M] (True: real) where padding matters. An encoder's: `forward(inputs) ->
    [B x M x D]`; an exchanger's: `forward(inputs, d2, d3, mask2d, mask3d) -> (d2, d3)`; a matcher's runs on
    descriptors as it needs, and its own `__call__` turns the scores into `Matches`.
    """

    def prepare(
        self,
        frame: Frame,
        *keypoints: Keypoints2D | Keypoints3D,
        device: Device = "cpu",
        cache: dict | None = None,
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs (no batch dim), made on the CPU; `keypoints` are those of the stage's kind
        (`keypoints_of`). `cache`, a per-frame dict kept across steps and runs, holds what the protocol's transform
        does not change (point grouping): the stage fills it. Only a matcher's sees the ground truth (training)."""
        raise NotImplementedError

    def batch_loss(
        self, inputs: Mapping[str, torch.Tensor], features: Features, mask2d: torch.Tensor, mask3d: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """a trainable matcher's loss on `prepare`d supervision and batched descriptors, the mean over the frames."""
        raise NotImplementedError(f"{self.label} does not train")

    def keypoints_of(self, kp2d: Keypoints2D, kp3d: Keypoints3D) -> tuple[Keypoints2D | Keypoints3D, ...]:
        """the keypoints this stage's kind takes, in `prepare`'s order."""
        return {"encoder2d": (kp2d,), "encoder3d": (kp3d,)}.get(self.kind, (kp2d, kp3d))

    def one(self, frame: Frame, *keypoints: Keypoints2D | Keypoints3D) -> dict[str, torch.Tensor]:
        """one frame's inputs as a batch of one, on the stage's device."""
        return {k: v[None] for k, v in self.prepare(frame, *keypoints, device=self.device).items()}

    def __call__(self, frame: Frame, *args: Any) -> Any:
        """the per-frame stage call of an encoder (`prepare`, a batch of one, `forward`) or an exchanger (the same,
        after the checks every exchanger makes: descriptors on both sides, `descriptor_dim` wide)."""
        if self.kind in ("encoder2d", "encoder3d"):
            return self.batched(self.one(frame, *args))[0].float()
        if self.kind == "exchanger":
            return self._exchange(frame, *args)
        raise NotImplementedError(f"{self.label}: a {self.kind} writes its own per-frame call")

    def _exchange(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Features:
        if features.desc2d is None or features.desc3d is None:
            raise StageError(self.label, "needs descriptors on both sides (an encoder2d and an encoder3d)")
        width = self.conf.get("descriptor_dim")
        for desc in (features.desc2d, features.desc3d):
            if width is not None and desc.shape[1] != width:
                raise StageError(self.label, f"expects {width}-wide descriptors, got {desc.shape[1]}")
        if len(kp2d) == 0 or len(kp3d) == 0:  # nothing to attend to; the matcher will find no match
            return features
        device = self.device
        d2, d3 = self.batched(
            self.one(frame, kp2d, kp3d), features.desc2d.to(device)[None], features.desc3d.to(device)[None]
        )
        return Features(desc2d=d2[0].float(), desc3d=d3[0].float())

    def loss(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """`batch_loss` on this frame alone (a batch of one); frame must carry T_gt."""
        device = self.device
        one = [None if d is None else d.to(device)[None] for d in (features.desc2d, features.desc3d)]
        masks = [torch.ones(1, n, dtype=torch.bool, device=device) for n in (len(kp2d), len(kp3d))]
        return self.batch_loss(self.one(frame, kp2d, kp3d), Features(*one), *masks)


def width_mismatch(component: Component, upstream: Mapping[str, Component], keys: Sequence[str]) -> str | None:
    """why one of component's width keys (descriptor_dim, global_dim) disagrees with an upstream stage's, or None."""
    for kind in ("encoder2d", "encoder3d", "exchanger"):
        other = upstream.get(kind)
        theirs = getattr(other, "conf", {}) if other is not None else {}
        for key in keys:
            if key in theirs and theirs[key] != component.conf[key]:
                return f"{component.label} has {key} {component.conf[key]} but {other.label} has {key} {theirs[key]}"
    return None
