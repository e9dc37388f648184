"""Write reference vectors of the authors' VP2P-Match modules, run from their checkout on CPU.

    /tmp/tsvenv/bin/python tools/reference/vp2p.py --checkout /work/peers/VP2P-Match \
        --frame ../shared/data/kitti_odometry/sequences/00 --frame-index 000000 --out tests/data/vp2p_reference \
        [--n 1024] [--seed 0] [--salt ""]

Needs torchsparse 2.0.0 importable (built from source; tools/reference/sparse.py's CPU stand-ins are applied) and
open3d. Today it covers the image branch (`models/network_img/resnet.py`'s Image_ResNet, `resnet.*`), the point
branch (`models/pointTransformer/point_transformer.py`'s PointsEncoder_pointwise with `is_pc_norm=False`,
`point_transformer.*`; pointnet2_ops, CUDA only, stood in for by tools/reference/pointnet2_cpu.py) and the voxel
branch (`models/spvnas/models/semantic_kitti/spvcnn.py`'s SPVCNN as `models/triplet_network.py` builds and feeds it:
cr 0.5, 0.05 m voxels, 128 outputs); the fusion and the heads are not recorded yet. Inputs: the
frame's camera-2 image at half resolution (the authors' scale), its centre `--image-size` crop; the frame's scan,
voxel-downsampled at 0.1 m with normals from a 0.6 m neighbourhood (the layout of the authors' `voxel0.1-SNr0.6`
files), `n` points drawn with `seed`. Weights: the recipe of ../shared/data/edgeregnet_reference/README.md
(`crc32(key + salt)`, kernels scaled by their fan-in), for the authors' state dict keys (`resnet.*`,
`voxel_branch.*`, as VP2PMatchNet names the branches). Written: `inputs.npz` (pc,
intensity, sn channels first; img [3 x H x W] in [0, 1]), `outputs.npz` (`image_branch.*`: global [512], the /32
map s32 and the upsampling stages f16, f8, mid; `point_branch.*`: the sampled centres l1_xyz, l2_xyz, the features
after each transformer l1_down, l2_down, l2_up, l1_up, global [512], pointwise [128 x n]; `voxel_branch.*`: x0
after the stem, x4 after the encoder, y2 and y4 after the decoder's halves, devox0-devox3 each trilinear read,
pointwise [128 x n] and global [128]), `state_dict_shapes.json`, `weights.sha256`, `meta.json`.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import torch
import torch.utils.hooks

from i2pbench.testing.recipe import recipe_state

CLOUD = ("pc", "intensity", "sn")  # VP2PMatchNet's point inputs, channels first


def load_sibling(name: str):
    """a module of this folder (tools/reference is no package)."""
    spec = importlib.util.spec_from_file_location(f"reference_{name}", Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def frame_image(frame: Path, index: str, size: tuple[int, int]) -> np.ndarray:
    """[3 x H x W] float32 in [0, 1]: the frame's camera-2 image at half resolution (the authors' scale), the centre
    `size` crop (the modules are convolutional: a crop proves the same function as the full 160 x 512 input)."""
    image = cv2.cvtColor(cv2.imread(str(frame / "image_2" / f"{index}.png")), cv2.COLOR_BGR2RGB)
    image = cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_LINEAR)
    top, left = (image.shape[0] - size[0]) // 2, (image.shape[1] - size[1]) // 2
    crop = image[top : top + size[0], left : left + size[1]]
    return np.ascontiguousarray(crop.transpose(2, 0, 1), dtype=np.float32) / 255


def frame_points(frame: Path, index: str, n: int, seed: int) -> dict[str, np.ndarray]:
    """pc [3 x n], intensity [1 x n], sn [3 x n] from the frame's scan, as described in the module docstring."""
    scan = np.fromfile(frame / "velodyne" / f"{index}.bin", np.float32).reshape(-1, 4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan[:, :3].astype(np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(np.repeat(scan[:, 3:4].astype(np.float64), 3, axis=1))
    cloud = cloud.voxel_down_sample(0.1)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(0.6))
    points, normals = np.asarray(cloud.points), np.asarray(cloud.normals)
    chosen = np.sort(np.random.default_rng(seed).choice(len(points), n, replace=False))
    return {
        "pc": points[chosen].T.astype(np.float32),
        "intensity": np.asarray(cloud.colors)[chosen, :1].T.astype(np.float32),
        "sn": normals[chosen].T.astype(np.float32),
    }


Recorder = dict[str, torch.Tensor]


def hook(module: torch.nn.Module, out: Recorder, name: str, pick) -> torch.utils.hooks.RemovableHandle:
    """record `pick(output)` of `module` under `name` each time it runs."""
    return module.register_forward_hook(lambda m, i, o: out.__setitem__(name, pick(o).clone()))


def image_branch(branch: torch.nn.Module, inputs: dict[str, np.ndarray]) -> Recorder:
    """the authors' Image_ResNet on the image: global, s32 and the three upsampling stages."""
    out: Recorder = {}
    handles = [hook(m, out, n, lambda o: o[0]) for n, m in (("f16", branch.up_conv1), ("f8", branch.up_conv2))]
    handles += [hook(branch.up_conv3, out, "mid", lambda o: o[0]), hook(branch.encoder, out, "s32", lambda o: o[-2][0])]
    with torch.no_grad():
        out["global"] = branch(torch.from_numpy(inputs["img"]).unsqueeze(0))[0][0]
    for handle in handles:
        handle.remove()
    return out


def point_branch(branch: torch.nn.Module, inputs: dict[str, np.ndarray]) -> Recorder:
    """the authors' PointsEncoder_pointwise (is_pc_norm False) on the cloud: centres, each transformer's output."""
    out: Recorder = {}
    handles = [
        hook(m, out, n, lambda o: o[0])
        for n, m in (
            ("l1_down", branch.transformer_start_1), ("l2_down", branch.transformer_start_2),
            ("l2_up", branch.transformer_end_2), ("l1_up", branch.transformer_end_1),
        )
    ]  # fmt: skip
    handles += [
        hook(m, out, n, lambda o: o[0][0]) for n, m in (("l1_xyz", branch.sa_module_1), ("l2_xyz", branch.sa_module_2))
    ]
    with torch.no_grad():
        global_feat, pointwise = branch(torch.from_numpy(np.concatenate([inputs[k] for k in CLOUD])).unsqueeze(0))
    out["global"], out["pointwise"] = global_feat[0], pointwise[0]
    for handle in handles:
        handle.remove()
    return out


def voxel_branch(spvcnn, branch: torch.nn.Module, inputs: dict[str, np.ndarray]) -> Recorder:
    """the authors' SPVCNN fed as triplet_network.py feeds it: the stem, encoder, decoder halves, trilinear reads."""
    out: Recorder = {}
    reads, to_point = [], spvcnn.voxel_to_point

    def recorded(x, z, nearest=False):
        result = to_point(x, z, nearest)
        reads.append(result.F.clone())
        return result

    spvcnn.voxel_to_point = recorded
    stages = (("x0", branch.stem), ("x4", branch.stage4), ("y2", branch.up2[1]), ("y4", branch.up4[1]))
    handles = [hook(m, out, n, lambda o: o.F) for n, m in stages]
    pc, intensity, sn = (torch.from_numpy(inputs[k]).unsqueeze(0) for k in CLOUD)
    feats = torch.cat((pc, intensity, sn), dim=1).transpose(2, 1).reshape(-1, 7)  # triplet_network.py's math
    corrds = pc.transpose(2, 1) - torch.min(pc.transpose(2, 1), dim=1, keepdim=True)[0]
    corrds = torch.round(corrds.reshape(-1, 3) / 0.05)
    corrds = torch.cat((corrds, torch.zeros(len(corrds), 1)), dim=-1)
    with torch.no_grad():
        global_feat, pointwise = branch(feats, corrds, 1)
    spvcnn.voxel_to_point = to_point
    for handle in handles:
        handle.remove()
    out.update({f"devox{i}": r for i, r in enumerate(reads)})
    out["pointwise"], out["global"] = pointwise[0], global_feat[0]
    return out


def whole_network(net: torch.nn.Module, inputs: dict[str, np.ndarray]) -> Recorder:
    """VP2PMatchNet.forward, its `.cuda()` (the batch indices) a no-op on this CPU."""
    tensors = [torch.from_numpy(inputs[k]).unsqueeze(0) for k in (*CLOUD, "img")]
    cuda, torch.Tensor.cuda = torch.Tensor.cuda, lambda self, *args, **kwargs: self
    try:
        with torch.no_grad():
            pixel_feat, point_feat, img_score, pc_score = net(*tensors)
    finally:
        torch.Tensor.cuda = cuda
    return {
        "pixel_feat": pixel_feat[0],
        "point_feat": point_feat[0],
        "img_score": img_score[0],
        "pc_score": pc_score[0],
    }


def run_network(checkout: Path, inputs: dict[str, np.ndarray], salt: str) -> tuple[dict, dict, str, dict]:
    """the authors' VP2PMatchNet with recipe weights: (outputs, state dict shapes, weights sha256, parameters)."""
    load_sibling("pointnet2_cpu").install()
    sys.path.insert(0, str(checkout))
    import models.spvnas.models.semantic_kitti.spvcnn as spvcnn  # the authors' modules, from the checkout
    from models.triplet_network import VP2PMatchNet
    from utils.options import Options

    net = VP2PMatchNet(Options())
    shapes = {k: list(v.shape) for k, v in net.state_dict().items()}
    state, digest = recipe_state(shapes, salt)
    net.load_state_dict(state)
    net.eval()
    parts = {
        "image_branch": (net.resnet, image_branch(net.resnet, inputs)),
        "point_branch": (net.point_transformer, point_branch(net.point_transformer, inputs)),
        "voxel_branch": (net.voxel_branch, voxel_branch(spvcnn, net.voxel_branch, inputs)),
        "network": (net, whole_network(net, inputs)),
    }
    outputs = {f"{part}.{k}": v.numpy() for part, (_, out) in parts.items() for k, v in out.items()}
    parameters = {part: sum(p.numel() for p in module.parameters()) for part, (module, _) in parts.items()}
    return outputs, shapes, digest, parameters


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkout", type=Path, required=True, help="junshengzhou/VP2P-Match")
    parser.add_argument("--frame", type=Path, required=True, help="a KITTI odometry sequence folder")
    parser.add_argument("--frame-index", default="000000")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--n", type=int, default=1024, help="points drawn from the downsampled scan")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--salt", default="")
    parser.add_argument("--image-size", type=int, nargs=2, default=(96, 256), help="crop of the half-size image")
    args = parser.parse_args()
    torch.set_num_threads(1)
    load_sibling("sparse").add_cpu_stand_ins()
    inputs = frame_points(args.frame, args.frame_index, args.n, args.seed)
    inputs["img"] = frame_image(args.frame, args.frame_index, tuple(args.image_size))
    outputs, shapes, digest, parameters = run_network(args.checkout, inputs, args.salt)
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "inputs.npz", **inputs)
    np.savez_compressed(args.out / "outputs.npz", **outputs)
    (args.out / "state_dict_shapes.json").write_text(json.dumps(shapes, indent=0) + "\n")
    (args.out / "weights.sha256").write_text(f"{digest}  recipe, salt {args.salt!r}\n")
    meta = {
        "frame": "/".join(args.frame.resolve().parts[-2:]),
        "frame_index": args.frame_index,
        "n": args.n,
        "seed": args.seed,
        "salt": args.salt,
        "checkout": "junshengzhou/VP2P-Match be76104",
        "modules": ["image_branch", "point_branch", "voxel_branch", "network"],
        "image_size": list(args.image_size),
        "parameters": parameters,
    }
    (args.out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")


if __name__ == "__main__":
    main()
