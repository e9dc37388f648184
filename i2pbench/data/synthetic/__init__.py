"""The embedded synthetic dataset: procedural street scenes rendered for a KITTI-like camera and 64-beam LiDAR.

Splits: sequence "00" = train, "01" = val, "02" = test. `kitti_writer.generate_kitti` writes any sequences;
`nuscenes_writer` writes the same scenes as a nuScenes dataroot.
"""

from .dataset import SyntheticStreets, generate
from .version import GENERATOR_VERSION

__all__ = ["GENERATOR_VERSION", "SyntheticStreets", "generate"]
