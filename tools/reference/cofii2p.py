"""Reference vectors of CoFiI2P computed by its authors' code (WHU-USI3DV/CoFiI2P, a checkout passed on the command
line and imported from there, never copied): the network of model/network.py built from `Options_KITTI` with seeded
weights (the recipe of ../shared/data/edgeregnet_reference/README.md, `crc32(key + salt)`), run in eval mode on one
real KITTI frame prepared as data/kitti.py's 'val' mode prepares one, recording the inputs, every module's output,
the outputs of the forward's 'val' and 'test' modes and train.py's losses.

    python tools/reference/cofii2p.py --checkout /work/peers/CoFiI2P \
        --frame ../shared/data/kitti_odometry/sequences/00 --frame-index 0 --salt "" --seed 0 --n 2048 \
        --out tests/data/reference/cofii2p

Needs `einops` (their transformer imports it) and open3d. What had to change for their code to run here, in this
script only (docs/methods.md lists them):
- `torch.Tensor.cuda` returns the tensor itself (network.py:105,156,180-181 move tensors to the GPU);
- open3d.ml's `KNNSearch` (preprocess_data.py:4,75, a CUDA/compiled op this open3d has not) is stood in for by their
  own pure-torch `knn` of the same file, flattened as KNNSearch's `neighbors_index`;
- their kernel_points.py writes the kernel disposition file it optimises into the checkout: its `__file__` is moved to
  a temporary folder, so the file goes there (the optimisation itself is theirs, seeded by --seed);
- the loader reads files made by scripts partly unreleased (img_P2, K_P2, pc_npy_with_normal, as CorrI2P's: the
  README points there; docs/datasets.md says what each holds): here the scan as tools/reference/corri2p.py's
  equivalent makes it (0.1 m voxels with open3d normals), the whole RGB image and K = P2[:, :3] (data/kitti.py never
  reads options.py's `crop_original_top_rows`);
- the loader draws up to `num_kpt` = 64 anchors and train.py gathers exactly 64: with `--n` points the coarse level
  has n / 16 super-points, fewer of them in view, so `num_kpt` here is the number both draws can give.

Written: inputs.npz (the image, the pyramid as `points_i`, `neighbors_i`, `subsampling_i`, `upsampling_i` (int16 when
they fit), `feats`, the loader's anchors, and each KPConv's `kernel_points` under its state-dict key: the recipe
covers the learned tensors, the dispositions are their load_kernels'), outputs.npz (a tensor of more than SAMPLE
elements is kept as its flat values every `step`-th, `step` in meta.json's `sampled`), state_dict_shapes.json (the
learned tensors), weights.sha256 and meta.json.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import itertools
import json
import math
import random
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import cv2
import numpy as np
import torch
from i2pbench_cofii2p.official.reference import NETWORK_OUTPUTS

from i2pbench.testing.recipe import recipe_state

IMAGE_H, IMAGE_W, SCALE = 160, 512, 0.5  # options.py Options_KITTI; kitti.py:306-320
NUM_KPT = 64  # options.py num_kpt
SAMPLE = 8192  # largest tensor kept whole in outputs.npz


def load_sibling(name: str) -> types.ModuleType:
    """a module of this folder (tools/reference is no package)."""
    spec = importlib.util.spec_from_file_location(f"reference_{name}", Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class KNNSearchStandIn:
    """open3d.ml.torch.layers.KNNSearch(points, queries, k) -> .neighbors_index, flat, by their preprocess `knn`."""

    def __init__(self, **_options) -> None:
        pass

    def __call__(self, points: torch.Tensor, queries: torch.Tensor, k: int) -> types.SimpleNamespace:
        knn = sys.modules["model.kpconv.preprocess_data"].knn
        return types.SimpleNamespace(neighbors_index=knn(points, queries, k).reshape(-1))


def import_authors(checkout: Path, scratch: Path) -> dict[str, types.ModuleType]:
    """their modules from the checkout, with the stand-ins of the module docstring installed first."""
    layers = types.ModuleType("open3d.ml.torch.layers")
    layers.KNNSearch, layers.FixedRadiusSearch = KNNSearchStandIn, None
    sys.modules |= {"open3d.ml": types.ModuleType("open3d.ml"), "open3d.ml.torch": types.ModuleType("open3d.ml.torch"),
                    "open3d.ml.torch.layers": layers}  # fmt: skip
    torch.Tensor.cuda = lambda self, *args, **kwargs: self
    sys.path.insert(0, str(checkout))
    kernels = importlib.import_module("model.kpconv.kernel_points")
    kernels.__file__ = str(scratch / "kernel_points.py")
    names = {"network": "model.network", "loss": "model.loss", "options": "data.options",
             "preprocess": "model.kpconv.preprocess_data"}  # fmt: skip
    return {short: importlib.import_module(name) for short, name in names.items()}


def scale_k(K: np.ndarray, s: float) -> np.ndarray:
    out = s * K
    out[2, 2] = 1
    return out


def random_motion() -> np.ndarray:
    """kitti.py generate_random_transform with Options_KITTI: t on x and z in [-10, 10], a turn about y in
    [-2 pi, 2 pi] (R = Rz Ry Rx, the x and z angles drawn from [0, 0]); the draws in their order."""
    t = [random.uniform(-10, 10), random.uniform(-0, 0), random.uniform(-10, 10)]
    angles = [random.uniform(-0.0, 0.0), random.uniform(-2 * math.pi, 2 * math.pi), random.uniform(-0.0, 0.0)]
    cx, sx, cy, sy, cz, sz = (f(a) for a in angles for f in (math.cos, math.sin))
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    P = np.identity(4, dtype=np.float32)
    P[:3, :3] = Rz @ Ry @ Rx
    P[:3, 3] = t
    return P


def frame_cloud(corri2p: types.ModuleType, frame: Path, index: int, n: int) -> tuple:
    """kitti.py:266-284: the preprocessed scan in camera 2's frame, voxelised at 0.1 m, n random points."""
    calib = corri2p.read_calib(frame / "calib.txt")
    points, intensity, normals = corri2p.scan_with_normals(frame / "velodyne" / f"{index:06d}.bin")
    Tr = np.eye(4)
    Tr[:3] = calib["Tr"]
    P_Tr = corri2p.camera_from_projection(calib["P2"]) @ Tr
    points, normals = P_Tr[:3, :3] @ points + P_Tr[:3, 3:], P_Tr[:3, :3] @ normals
    points, intensity, normals = (a.astype(np.float32) for a in corri2p.voxel(points, intensity, normals, 0.1))
    if points.shape[1] < n:
        raise SystemExit(f"{frame}: {points.shape[1]} voxels, fewer than --n {n}")
    pick = np.random.choice(points.shape[1], n, replace=False)
    return points[:, pick], intensity[:, pick], normals[:, pick], calib


def frame_image(frame: Path, index: int, calib: dict) -> tuple[np.ndarray, np.ndarray]:
    """the whole RGB image scaled by 0.5 and centre-cropped (kitti.py:306-320) and its K."""
    image = cv2.cvtColor(cv2.imread(str(frame / "image_2" / f"{index:06d}.png")), cv2.COLOR_BGR2RGB)
    K = calib["P2"][:, :3].copy()
    size = (int(round(image.shape[1] * SCALE)), int(round(image.shape[0] * SCALE)))
    image, K = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR), scale_k(K, SCALE)
    dx, dy = int((image.shape[1] - IMAGE_W) / 2), int((image.shape[0] - IMAGE_H) / 2)
    K[0, 2] -= dx
    K[1, 2] -= dy
    return np.ascontiguousarray(image[dy : dy + IMAGE_H, dx : dx + IMAGE_W]), K


def anchors(authors: dict, pyramid: dict, K: np.ndarray, P: np.ndarray) -> dict[str, np.ndarray]:
    """kitti.py:323-373: the super-points seen in the stride-8 map, as many outside it, their super-pixels, their
    stride-2 pixels and patch centres, their nearest stage-1 points."""
    K_2, K_4 = scale_k(K, 0.5), scale_k(K, 0.125)
    nodes = pyramid["points"][-1].numpy().T
    R_inv = np.linalg.inv(P[:3, :3])
    projected = K_4 @ (R_inv @ nodes - R_inv @ P[:3, 3:])
    projected[:2] /= projected[2:]
    xy = np.floor(projected[:2] + 0.5)
    seen = (xy[0] >= 1) & (xy[0] <= IMAGE_W / 8 - 3) & (xy[1] >= 1) & (xy[1] <= IMAGE_H / 8 - 3) & (projected[2] > 0)
    inline = np.where(seen)[0][np.random.permutation(seen.sum())[:NUM_KPT]]
    outline = np.where(~seen)[0][np.random.permutation((~seen).sum())[:NUM_KPT]]
    kpt = min(len(inline), len(outline))
    inline, outline = inline[:kpt], outline[:kpt]
    fine = K_2 @ (R_inv @ nodes[:, inline] - R_inv @ P[:3, 3:])
    fine_xy = np.floor(fine[:2] / fine[2:])
    if not ((fine_xy >= 0).all() and (fine_xy[0] <= IMAGE_W / 2 - 1).all() and (fine_xy[1] <= IMAGE_H / 2 - 1).all()):
        raise SystemExit("an anchor's stride-2 pixel lies outside the image (kitti.py:367 asserts it does not)")
    nearest = authors["network"].point2node(pyramid["points"][1], pyramid["points"][-1][torch.from_numpy(inline)])
    return {
        "pc_kpt_idx": inline, "pc_outline_idx": outline, "K": K_2.astype(np.float32), "K_4": K_4.astype(np.float32),
        "P": np.linalg.inv(P).astype(np.float32), "fine_xy": fine_xy.astype(np.int32),
        "coarse_img_kpt_idx": (xy[1, inline] * IMAGE_W / 8 + xy[0, inline]).astype(np.int64),
        "fine_center_kpt_coors": (xy[:, inline] * 4).astype(np.int32), "fine_pc_inline_index": nearest.numpy(),
    }  # fmt: skip


def prepare(authors: dict, frame: Path, index: int, n: int) -> tuple[dict, dict[str, np.ndarray]]:
    """one frame as kitti.py's 'val' mode gives it -> (pc_data_dict, the other inputs)."""
    corri2p = load_sibling("corri2p")
    points, intensity, normals, calib = frame_cloud(corri2p, frame, index, n)
    P = random_motion()
    points, normals = P[:3, :3] @ points + P[:3, 3:], P[:3, :3] @ normals
    pyramid = authors["preprocess"].precompute_point_cloud_stack_mode(points, intensity, normals, n, 5)
    for key in ("neighbors", "subsampling", "upsampling"):
        pyramid[key] = [t.long() for t in pyramid[key]]
    pyramid["feats"] = torch.from_numpy(np.concatenate([intensity, normals]).T.astype(np.float32))
    image, K = frame_image(frame, index, calib)
    return pyramid, {"image": image} | anchors(authors, pyramid, K, P)


def pyramid_arrays(pyramid: dict) -> dict[str, np.ndarray]:
    out = {"feats": pyramid["feats"].numpy()}
    for key in ("points", "neighbors", "subsampling", "upsampling"):
        for i, value in enumerate(pyramid[key]):
            array = value.numpy()
            out[f"{key}_{i}"] = array.astype(np.int16) if key != "points" and array.max() < 2**15 else array
    return out


def build(authors: dict, salt: str) -> tuple[torch.nn.Module, dict, dict[str, np.ndarray], str]:
    """their network with the recipe's weights and their own kernel dispositions -> (net, learned shapes,
    dispositions by key, sha256 of the recipe's tensors)."""
    net = authors["network"].CoFiI2P(authors["options"].Options_KITTI()).eval()
    state = net.state_dict()
    kernels = {k: v.numpy() for k, v in state.items() if k.endswith("kernel_points")}
    shapes = {k: list(v.shape) for k, v in state.items() if k not in kernels}
    weights, sha = recipe_state(shapes, salt)
    net.load_state_dict(weights | {k: torch.from_numpy(v) for k, v in kernels.items()})
    return net, shapes, kernels, sha


def hooks(net: torch.nn.Module, record: dict) -> None:
    """every module's output into `record` under the names CoFiI2PNetwork's trace uses."""

    def keep(name):
        return lambda _module, _args, output: record.__setitem__(name, output)

    for name, module in net.pc_encoder.named_children():
        module.register_forward_hook(keep(f"pc_encoder.{name}"))
    net.img_encoder.register_forward_hook(lambda _m, _a, out: record.update(
        zip(("img_s2", "img_s4", "img_s8_raw", "img_s16", "img_s32", "img_global"), out, strict=True)))  # fmt: skip
    for name in ("pc_feature_layer", "img_upsample_1", "img_upsample_2", "pc_score_layer", "img_score_layer"):
        getattr(net, name).register_forward_hook(keep(name))
    net.img_pos_encoding.register_forward_hook(keep("img_pos"))
    net.pc_pos_encoding.register_forward_hook(keep("pc_pos"))
    for i, layer in enumerate(net.transformer.layers):
        calls = itertools.cycle(("image", "points"))
        layer.register_forward_hook(lambda _m, _a, out, i=i, calls=calls: record.__setitem__(
            f"transformer.layers.{i}.{next(calls)}", out))  # fmt: skip


def watch_selection(authors: dict, record: dict) -> None:
    """their fine_process and point2node, recording what the 'test' mode's last call returned."""
    network = authors["network"]
    fine_process, point2node = network.fine_process, network.point2node

    def selection(score, pc, img, thrs=0.9):
        xy, index = fine_process(score, pc, img, thrs=thrs)
        record.update({"pc_inline_index": index, "score_threshold": torch.tensor(thrs)})
        return xy, index

    def nodes(cloud, points):
        record["coarse_pc_index"] = point2node(cloud, points)
        return record["coarse_pc_index"]

    network.fine_process, network.point2node = selection, nodes


def losses(authors: dict, pyramid: dict, inputs: dict, out: tuple) -> dict[str, torch.Tensor]:
    """train.py:233-283 on one frame ('val' outputs): desc_loss + overlap_loss + fine_circle_loss."""
    loss = authors["loss"]
    t = {k: torch.from_numpy(np.asarray(v)) for k, v in inputs.items() if k != "image"}
    kpt, device = len(t["pc_kpt_idx"]), torch.device("cpu")
    img_features, pc_features, _, pc_score, patches, fine_pc = out[:6]
    h, w = img_features.shape[2:]
    img_xy = torch.cat((torch.linspace(0, w - 1, w).view(1, -1).expand(h, w)[None],
                        torch.linspace(0, h - 1, h).view(-1, 1).expand(h, w)[None])).reshape(2, -1)  # fmt: skip
    flat = img_features.contiguous().view(img_features.size(1), -1)
    img_inline = torch.gather(flat, index=t["coarse_img_kpt_idx"][None].expand(flat.size(0), kpt), dim=-1)
    xy_inline = torch.gather(img_xy, index=t["coarse_img_kpt_idx"][None].expand(2, kpt), dim=-1)
    xyz = torch.gather(pyramid["points"][-1].T, index=t["pc_kpt_idx"][None].expand(3, kpt), dim=-1)
    pc_inline = torch.gather(pc_features, index=t["pc_kpt_idx"].expand(pc_features.size(0), kpt), dim=-1)
    projected = torch.mm(t["K_4"], torch.mm(t["P"][:3, :3], xyz) + t["P"][:3, 3:])
    xy = projected[:2] / projected[2:]
    mask = (torch.sqrt(torch.sum(torch.square(xy_inline[:, :, None] - xy[:, None]), 0)) <= 1.0).float()
    desc, _ = loss.desc_loss(device, img_inline, pc_inline, mask, pos_margin=0.2, neg_margin=1.8)
    coarse = loss.overlap_loss(device, torch.squeeze(pc_score[:, :, t["pc_kpt_idx"]]),
                               torch.squeeze(pc_score[:, :, t["pc_outline_idx"]]))  # fmt: skip
    relative = t["fine_xy"] - t["fine_center_kpt_coors"] + 2
    fine = loss.fine_circle_loss(device, patches, fine_pc, relative[1] * 4 + relative[0], kpt)
    return {"loss_desc": desc, "loss_coarse": coarse, "loss_fine": fine, "loss": desc + coarse + fine,
            "correspondence_mask": mask}  # fmt: skip


def run(authors: dict, net, pyramid: dict, inputs: dict) -> dict[str, np.ndarray]:
    """their forward in 'val' mode (losses, the training patches) and in 'test' mode (outputs, selection)."""
    record: dict = {}
    hooks(net, record)
    watch_selection(authors, record)
    t = {k: torch.from_numpy(np.asarray(inputs[k])) for k in ("fine_center_kpt_coors", "fine_xy",
                                                                "fine_pc_inline_index")}  # fmt: skip
    image = torch.from_numpy(inputs["image"].astype(np.float32) / 255.0).permute(2, 0, 1)[None].contiguous()
    with torch.no_grad():
        val = net(pyramid, image, t["fine_center_kpt_coors"], t["fine_xy"], t["fine_pc_inline_index"], "val")
        tensors = {f"val.{k}": v for k, v in zip(NETWORK_OUTPUTS[4:6], val[4:6], strict=True)}
        tensors |= losses(authors, pyramid, inputs, val)
        test = net(pyramid, image, None, None, None, "test")
    tensors |= record | dict(zip(NETWORK_OUTPUTS, test, strict=True))
    return {k: v.numpy() for k, v in tensors.items()}


def sampled(tensors: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """tensors larger than SAMPLE elements kept as every step-th flat value -> (tensors, {name: shape, step})."""
    kept, steps = {}, {}
    for name, value in tensors.items():
        if value.size > SAMPLE:
            step = -(-value.size // SAMPLE)
            kept[name] = value.reshape(-1)[::step].copy()
            steps[name] = {"shape": list(value.shape), "step": step}
        else:
            kept[name] = value
    return kept, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkout", type=Path, required=True, help="a checkout of WHU-USI3DV/CoFiI2P")
    parser.add_argument("--frame", type=Path, required=True, help="a KITTI odometry sequence folder")
    parser.add_argument("--frame-index", type=int, default=0)
    parser.add_argument("--salt", default="")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n", type=int, default=2048, help="points (the authors' 20,480; 2,048 is the least that "
                        "leaves the coarse stage its 128 neighbours, and keeps a set small)")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        authors = import_authors(args.checkout.resolve(), Path(scratch))
        np.random.seed(args.seed)
        random.seed(args.seed)
        torch.manual_seed(args.seed)
        pyramid, inputs = prepare(authors, args.frame, args.frame_index, args.n)
        net, shapes, kernels, sha = build(authors, args.salt)
        tensors, steps = sampled(run(authors, net, pyramid, inputs))
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "inputs.npz", **inputs, **pyramid_arrays(pyramid), **kernels)
    np.savez_compressed(args.out / "outputs.npz", **tensors)
    (args.out / "state_dict_shapes.json").write_text(json.dumps(shapes, indent=0) + "\n")
    (args.out / "weights.sha256").write_text(sha + "\n")
    commit = subprocess.run(["git", "-C", str(args.checkout), "rev-parse", "HEAD"], capture_output=True, text=True)
    frame = args.frame.resolve()
    meta = {"frame": str(frame.relative_to(frame.parents[2])), "frame_index": args.frame_index, "salt": args.salt,
            "seed": args.seed, "n": args.n, "num_kpt": len(inputs["pc_kpt_idx"]), "sampled": steps,
            "score_threshold": float(tensors["score_threshold"]), "pairs": len(tensors["pc_inline_index"]),
            "authors_commit": commit.stdout.strip() or None, "torch": torch.__version__}  # fmt: skip
    (args.out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
