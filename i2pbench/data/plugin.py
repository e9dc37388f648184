"""Entry point registering the built-in datasets (the nuScenes devkit is imported only when that dataset is used)."""

from ..plugins import hookimpl
from .kitti import KittiOdometry
from .nuscenes import NuScenes
from .synthetic import SyntheticStreets


@hookimpl
def register_datasets(register) -> None:
    register(KittiOdometry)
    register(NuScenes)
    register(SyntheticStreets)
