"""The dataset contract shared by KITTI, nuScenes, the synthetic set and third-party datasets."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from ..components import merge_conf
from ..errors import DataError
from ..types import SensorFrame


class Dataset:
    """A split of a dataset on disk. Subclasses set `name`, `splits`, `default_conf` and implement two methods.

    `conf["root"]` is the dataset's directory; when None it is read from the environment variable
    `I2PBENCH_<NAME>_ROOT` (e.g. `I2PBENCH_KITTI_ROOT`), so users keep their paths out of commands.
    """

    name: ClassVar[str] = ""
    splits: ClassVar[tuple[str, ...]] = ("train", "val", "test")
    default_conf: ClassVar[dict[str, Any]] = {"root": None}
    match_radius_px: ClassVar[float] = 3.0  # eps_c for this sensor set-up

    def __init__(self, split: str, conf: Mapping[str, Any] | None = None) -> None:
        if split not in self.splits:
            raise DataError(f"dataset {self.name!r} has no split {split!r}; choose one of {list(self.splits)}")
        self.split = split
        self.conf = merge_conf(self.default_conf, conf, f"dataset {self.name!r}")

    @property
    def root(self) -> Path:
        root = self.conf.get("root") or os.environ.get(f"I2PBENCH_{self.name.upper().replace('-', '_')}_ROOT")
        if not root:
            raise DataError(
                f"dataset {self.name!r}: no root directory; pass --data-root or set "
                f"I2PBENCH_{self.name.upper().replace('-', '_')}_ROOT"
            )
        return Path(root).expanduser()

    def frame_ids(self) -> list[str]:
        """Sorted ids of the frames in this split."""
        raise NotImplementedError

    def load(self, frame_id: str) -> SensorFrame:
        """Read one frame; raise DataError naming the file when it is malformed."""
        raise NotImplementedError

    def identity(self) -> dict[str, Any]:
        """What identifies this data for caching and leaderboards."""
        return {"dataset": self.name, "split": self.split, "root": str(self.conf.get("root") or "")}
