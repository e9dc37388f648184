"""A yaw-canonical frame for LiDAR points: an input normalisation that makes the encoders blind to the protocol's
random yaw and planar translation. Our addition for CPU-trainability, not the paper's (off in its configs).

The benchmark moves every scan by a random rotation about z and a translation in x, y. The paper's encoders learn
invariance to that from augmentation alone, which takes far more steps than a CPU gives. Instead, points can be
expressed in a frame built from their own geometry: origin at the centroid, x along the principal axis of the
horizontal spread (a street's direction), its sign fixed so the third moment along it is positive, y = z cross x,
z kept. The centroid, the principal axis and the moment all move with the points under any rotation about z and any
translation, so the canonical coordinates are the same whatever the random transform was (up to float rounding, and
except where the spread is isotropic and the axis ill-defined). Nothing from the pose or the ground truth is used.
"""

from __future__ import annotations

import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def canonical_yaw(offsets: torch.Tensor) -> torch.Tensor:
    """offsets [N x 3] from the centroid -> R [3 x 3], a rotation about z: canonical = offsets @ R.T."""
    planar = offsets[:, :2].double()
    _, vectors = torch.linalg.eigh(planar.t() @ planar)  # ascending eigenvalues: the last vector is the major axis
    axis = vectors[:, -1]
    if ((planar @ axis) ** 3).sum() < 0:
        axis = -axis
    x, y = axis.to(offsets.dtype), torch.stack([-axis[1], axis[0]]).to(offsets.dtype)
    zero = offsets.new_zeros(1)
    return torch.stack([torch.cat([x, zero]), torch.cat([y, zero]), offsets.new_tensor([0.0, 0.0, 1.0])])
