"""LiDAR keypoints where the surface bends: high local surface variation from a PCA of each point's neighbours.

Surface variation (Pauly et al. 2002) is l0 / (l0 + l1 + l2), with l0 <= l1 <= l2 the eigenvalues of the covariance
of a point's k nearest neighbours: 0 on a plane, up to 1/3 where points scatter in every direction (edges, corners).
"""

import numpy as np
from i2pbench.api import Extractor3D, Frame, Keypoints3D
from scipy.spatial import cKDTree


def surface_variation(xyz: np.ndarray, k: int) -> np.ndarray:
    """[N] surface variation of [N x 3] points over their k nearest neighbours (themselves included)."""
    k = min(k, len(xyz))
    if k < 3:
        return np.zeros(len(xyz))
    _, neighbours = cKDTree(xyz).query(xyz, k=k)
    local = xyz[neighbours] - xyz[neighbours].mean(axis=1, keepdims=True)  # [N x k x 3]
    covariance = np.einsum("nki,nkj->nij", local, local) / k
    eigenvalues = np.linalg.eigvalsh(covariance)  # ascending, [N x 3]
    total = eigenvalues.sum(axis=1)
    return np.divide(eigenvalues[:, 0], total, out=np.zeros(len(xyz)), where=total > 0)


class CurvatureExtractor(Extractor3D):
    """Points whose surface variation exceeds `threshold`, the `max_keypoints` highest kept, in point order."""

    name = "curvature"
    default_conf = {
        "max_keypoints": 3000,  # keep at most this many (the most curved); None keeps all
        "neighbours": 10,  # k of the k-nearest-neighbour PCA
        "threshold": 0.05,  # minimum surface variation (0 = plane, 1/3 = isotropic scatter)
    }

    def __call__(self, frame: Frame) -> Keypoints3D:
        finite = np.flatnonzero(np.isfinite(frame.points[:, :3]).all(axis=1))  # a corrupt return is never a keypoint
        variation = surface_variation(frame.points[finite, :3].astype(np.float64), int(self.conf["neighbours"]))
        candidates = np.flatnonzero(variation > self.conf["threshold"])
        strongest = candidates[np.argsort(-variation[candidates], kind="stable")[: self.conf["max_keypoints"]]]
        return Keypoints3D.from_index(frame, np.sort(finite[strongest]))
