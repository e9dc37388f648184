"""Run a peer's own KITTI dataset class (CorrI2P's kitti_pc_img_dataloader.py or CoFiI2P's data/kitti.py) from its
checkout, in a process of its own, and save what it returns for some dataset indices.

    python scripts/peer_kitti_loader.py corri2p /work/peers/CorrI2P ROOT OUT.npz 0 2 4

ROOT is a folder in the CorrI2P layout with sequences 09 and 10 (the loaders' test split, 'val'). The peer's code is
imported from the checkout as it is; stubbed, only what cannot run here: `np.int` (gone from numpy 2, used by their
FarthestSampler), torchvision when absent (only their training-time colour jitter uses it), and for CoFiI2P the
KPConv neighbour precomputation and its point2node (open3d.ml's CUDA/torch ops); the stub keeps the moved cloud that
CoFiI2P hands it, which is what is compared. Both generators are seeded per index with CoFiI2P's SeedSequence([index])
(CoFiI2P seeds them itself; CorrI2P seeds nothing, so this script does it the same way before each item).
"""

from __future__ import annotations

import math
import random
import sys
import types

import numpy as np


def _stub(name: str, **attrs) -> None:
    module = types.ModuleType(name)
    module.__dict__.update(attrs)
    sys.modules[name] = module


def _stub_unrunnable(peer: str) -> None:
    import torch

    np.int = int  # numpy < 1.24's alias, which their FarthestSampler still uses
    try:
        import torchvision  # noqa: F401
    except ImportError:
        _stub("torchvision")
        _stub("torchvision.transforms", ColorJitter=None)
        sys.modules["torchvision"].transforms = sys.modules["torchvision.transforms"]
    if peer == "cofii2p":

        def precompute(pc, intensity, sn, lengths, num_stages):
            cloud = torch.from_numpy(np.ascontiguousarray(pc.T))
            return {"points": [cloud] * num_stages, "neighbors": [torch.zeros(1)] * num_stages,
                    "subsampling": [torch.zeros(1)] * (num_stages - 1),
                    "upsampling": [torch.zeros(1)] * (num_stages - 1)}  # fmt: skip

        _stub("model")
        _stub("model.kpconv")
        _stub("model.kpconv.preprocess_data", precompute_point_cloud_stack_mode=precompute,
              precompute_point_cloud_cuda=None)  # fmt: skip
        _stub("model.network", point2node=lambda points, nodes: torch.zeros(len(nodes)))


def _dataset(peer: str, checkout: str, root: str):
    sys.path.insert(0, checkout)
    _stub_unrunnable(peer)
    if peer == "corri2p":
        import kitti_pc_img_dataloader as loader

        # eval_all.py's arguments: 40960 points, t_x and t_z within 10 m, a yaw within 2 pi
        return loader.kitti_pc_img_dataset(root, "val", 40960, P_tx_amplitude=10, P_ty_amplitude=0,
                                           P_tz_amplitude=10, P_Rx_amplitude=0, P_Ry_amplitude=2 * math.pi,
                                           P_Rz_amplitude=0)  # fmt: skip
    from data.kitti import kitti_pc_img_dataset
    from data.options import Options_KITTI

    options = Options_KITTI()
    options.data_path = root
    return kitti_pc_img_dataset(options, "val")


def _item(peer: str, dataset, index: int) -> dict[str, np.ndarray]:
    """The image (uint8 again), K of the 160 x 512 crop, moved points with reflectance, and P for one index."""
    (seed,) = np.random.SeedSequence([index]).generate_state(1)
    np.random.seed(int(seed))
    random.seed(int(seed))
    item = dataset[index]
    image = np.round(item["img"].permute(1, 2, 0).numpy() * 255.0).astype(np.uint8)
    if peer == "corri2p":  # K at 1/4 of the crop
        K, xyz, reflectance = item["K"].numpy().copy(), item["pc"].numpy(), item["intensity"].numpy()[0]
        K[:2] *= 4
    else:  # K at 1/2 of the crop; the cloud as the KPConv stub kept it
        K, xyz = item["K"].numpy().copy(), item["pc_data_dict"]["points"][0].numpy().T
        reflectance = item["pc_data_dict"]["feats"].numpy()[:, 0]
        K[:2] *= 2
    return {"image": image, "K": K, "points": np.vstack([xyz, reflectance[None]]).T, "P": item["P"].numpy()}


def main(argv: list[str]) -> None:
    peer, checkout, root, out, *indices = argv
    dataset = _dataset(peer, checkout, root)
    arrays = {}
    for index in map(int, indices):
        for key, value in _item(peer, dataset, index).items():
            arrays[f"{index}/{key}"] = value
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1:])
