"""Run a peer's own nuScenes dataset class (CoFiI2P's data/nuscenes.py or CorrI2P's nuscenes_pc_img_dataloader.py)
from its checkout, in a process of its own, and save what it returns for some dataset indices.

    python scripts/peer_nuscenes_loader.py cofii2p /work/peers/CoFiI2P ROOT OUT.npz 0 1 2

ROOT is a folder in that peer's nuScenes layout holding test/. The peer's code is imported from the checkout as it
is; stubbed, only what cannot run here, as scripts/peer_kitti_loader.py does: `np.int`, torchvision when absent,
and CoFiI2P's KPConv precomputation and point2node (the stub keeps the moved cloud CoFiI2P hands it, which is what
is compared). CoFiI2P seeds numpy and Python with the index itself; CorrI2P seeds nothing, so this script seeds
both with the index before each item, as i2pbench does.
"""

from __future__ import annotations

import random
import sys

import numpy as np
from peer_kitti_loader import _stub_unrunnable


def _precompute(pc, intensity, normals=None, lengths=None, num_stages=5):
    """CoFiI2P's KPConv precompute stubbed (its nuScenes loader passes `normals=`): the moved cloud kept."""
    import torch

    cloud = torch.from_numpy(np.ascontiguousarray(pc.T))
    return {
        "points": [cloud] * num_stages,
        "neighbors": [torch.zeros(1)] * num_stages,
        "subsampling": [torch.zeros(1)] * (num_stages - 1),
        "upsampling": [torch.zeros(1)] * (num_stages - 1),
    }


def _dataset(peer: str, checkout: str, root: str):
    sys.path.insert(0, checkout)
    _stub_unrunnable(peer)
    if peer == "cofii2p":
        sys.modules["model.kpconv.preprocess_data"].precompute_point_cloud_stack_mode = _precompute
    if peer == "corri2p":
        import nuscenes_pc_img_dataloader as loader
        from nuScenes import options

        return loader.nuScenesLoader(root, "test", options.Options())
    from data.nuscenes import nuscenes_pc_img_dataset
    from data.options import Options_Nuscenes

    options = Options_Nuscenes()
    options.data_path = root
    return nuscenes_pc_img_dataset(options, "test")


def _item(peer: str, dataset, index: int) -> dict[str, np.ndarray]:
    """The image (uint8 again), K of the 160 x 320 crop, moved points with intensity, and P for one index."""
    if peer == "corri2p":
        np.random.seed(index)
        random.seed(index)
    item = dataset[index]
    image = np.round(item["img"].permute(1, 2, 0).numpy() * 255.0).astype(np.uint8)
    if peer == "corri2p":  # K at 1/4 of the crop
        K = item["K"].numpy().astype(np.float64) / 0.25
        points = np.concatenate([item["pc"].numpy(), item["intensity"].numpy()], axis=0).T
    else:  # K at 1/2 of the crop; the cloud as handed to KPConv's precompute, intensity the first feature
        K = item["K"].numpy().astype(np.float64) / 0.5
        feats = item["pc_data_dict"]["feats"].numpy()
        points = np.column_stack([item["pc_data_dict"]["points"][0].numpy(), feats[:, 0]])
    K[2, 2] = 1.0
    return {"image": image, "K": K, "points": points.astype(np.float64), "P": item["P"].numpy().astype(np.float64)}


def main(argv: list[str]) -> None:
    peer, checkout, root, out, *indices = argv
    dataset = _dataset(peer, checkout, root)
    saved = {}
    for index in map(int, indices):
        for key, value in _item(peer, dataset, index).items():
            saved[f"{key}_{index}"] = value
    np.savez(out, **saved)


if __name__ == "__main__":
    main(sys.argv[1:])
