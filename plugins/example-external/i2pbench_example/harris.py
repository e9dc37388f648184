"""Image keypoints at Harris corners (OpenCV's goodFeaturesToTrack with the Harris response)."""

import cv2
import numpy as np
from i2pbench.api import Extractor2D, Frame, Keypoints2D


class HarrisExtractor(Extractor2D):
    """The strongest Harris corners, at least `min_distance` pixels apart, strongest first; deterministic."""

    name = "harris"
    default_conf = {
        "max_keypoints": 1000,  # keep at most this many corners (the strongest)
        "quality_level": 0.01,  # drop corners weaker than this fraction of the strongest one
        "min_distance": 3,  # pixels between kept corners
        "block_size": 3,  # neighbourhood of the corner response
        "k": 0.04,  # Harris detector free parameter
    }

    def __call__(self, frame: Frame) -> Keypoints2D:
        gray = cv2.cvtColor(np.ascontiguousarray(frame.image), cv2.COLOR_RGB2GRAY)
        corners = cv2.goodFeaturesToTrack(
            gray,
            maxCorners=int(self.conf["max_keypoints"]),
            qualityLevel=float(self.conf["quality_level"]),
            minDistance=float(self.conf["min_distance"]),
            blockSize=int(self.conf["block_size"]),
            useHarrisDetector=True,
            k=float(self.conf["k"]),
        )
        uv = np.zeros((0, 2), np.float32) if corners is None else corners.reshape(-1, 2).astype(np.float32)
        return Keypoints2D(uv)
