"""Entry point registering the built-in datasets, by import path: each dataset's module (and what it imports, e.g.
SciPy for nuScenes, the devkit only when that dataset is used) loads when the dataset is opened."""

from ..plugins import hookimpl


@hookimpl
def register_datasets(register) -> None:
    register("i2pbench.data.kitti:KittiOdometry", name="kitti")
    register("i2pbench.data.nuscenes:NuScenes", name="nuscenes")
    register("i2pbench.data.synthetic:SyntheticStreets", name="synthetic")
