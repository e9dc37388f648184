"""What the stages before one have produced so far. Each stage kind says what it takes from it and where its
output goes (`components.StageKind.arguments` and `.put`), so this module imports no stage declaration."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..types import Features, Keypoints2D, Keypoints3D, Matches


@dataclass(frozen=True)
class StageInputs:
    """What the stages before one have produced so far: the values a stage of any kind may be handed."""

    kp2d: Keypoints2D | None = None
    kp3d: Keypoints3D | None = None
    features: Features = field(default_factory=lambda: Features(None, None))
    matches: Matches | None = None
