"""Run CoFiI2P's own nuScenes build scripts (data/build_nuscenes/build_datainfo.py, then build_dataset.py) from its
checkout on a devkit dataroot, in a process of its own, to compare their files with i2pbench's export.

    python scripts/peer_nuscenes_build.py /work/peers/CoFiI2P ROOT OUT ACCUMULATION_SKIP

ROOT holds test/v1.0-test (the scripts' `root/mode` with mode "test"); OUT receives test/{pc,img,ext,int}. As
published the two scripts do not meet: build_datainfo writes `<mode>set_info.list` in its own folder and
build_dataset reads `dataset_info.list` from the dataroot, so this passes the list on; and build_dataset's
make_dataset reads a module-level `opt` made only under `__main__`, so this sets it. Options_Nuscenes is used as it
is but for `accumulation_frame_skip`, given on the command line (4 as published, for 20 Hz sweeps). Stubbed, only
torchvision when absent (imported, not used here). One process (thread_num 1) instead of their 20.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

from peer_kitti_loader import _stub


def main(argv: list[str]) -> None:
    checkout, root, out, skip = argv
    sys.path.insert(0, checkout)
    try:
        import torchvision  # noqa: F401
    except ImportError:
        _stub("torchvision")
        _stub("torchvision.transforms", ColorJitter=None)
        sys.modules["torchvision"].transforms = sys.modules["torchvision.transforms"]
    import data.build_nuscenes.build_datainfo as datainfo
    import data.build_nuscenes.build_dataset as build
    from nuscenes.nuscenes import NuScenes

    base = build.Options_Nuscenes

    class Options(base):
        def __init__(self) -> None:
            super().__init__()
            self.accumulation_frame_skip = int(skip)

    build.Options_Nuscenes = Options
    build.opt = Options()
    nusc = NuScenes(version="v1.0-test", dataroot=str(Path(root) / "test"), verbose=False)
    frames = datainfo.make_nuscenes_dataset(nusc, frame_skip=2, max_translation=10)
    with open(Path(root) / "test" / "dataset_info.list", "wb") as f:
        pickle.dump(frames, f)
    build.make_dataset_multiprocess(root, out, "test", build.opt, thread_num=1)


if __name__ == "__main__":
    main(sys.argv[1:])
