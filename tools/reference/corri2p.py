"""Reference vectors of CorrI2P computed by its authors' code (rsy6318/CorrI2P, a checkout passed on the command
line and imported from there, never copied): the network built from its `Options` with seeded weights (the recipe
of ../shared/data/edgeregnet_reference/README.md, `crc32(key + salt)`), run in eval mode on one real KITTI frame
prepared as its loader prepares one, recording the inputs, every module's output, the outputs and train.py's losses.

    python tools/reference/corri2p.py /work/peers/CorrI2P --frame ../shared/data/kitti_odometry/sequences/00 \
        --frame-index 0 --salt "" --seed 0 --n 2048 --out tests/data/reference/corri2p

What had to change for the code to run here, in this script only (docs/methods.md lists them):
- `index_max.forward_cuda_shared_mem` (a CUDA kernel, pointnet2.py:89,102) is replaced by `node_argmax`, a CPU
  stand-in returning, per node and channel, the first index of the largest feature among the node's points (index 0
  for an empty node, which the authors' mask then zeroes); `torch.cuda.device(-1)` is a no-op on CPU tensors;
- torchvision is stubbed: imagenet.py imports `load_state_dict_from_url`, called only for ImageNet weights, which
  the recipe overwrites;
- options.py builds 128 + 128 nodes while the loader samples 256 + 256 (kitti_pc_img_dataloader.py:107-108): the
  nodes here follow options.py; `input_pt_num` is set to `--n` (the encoder's node mask is built for that many);
- the loader reads files made by scripts partly unreleased (img_P2, K_P2, pc_npy_with_normal): here the scan is
  voxelised at 0.1 m with open3d normals (radius 0.6, 30 neighbours, oriented to +z) and nearest-point intensity
  (kitti_script/kitti_pc_bin_to_npy_with_downsample_sn.py), moved into camera 2's frame, voxelised again at 0.1 m
  (the loader), `--n` random points; the image (RGB) is the whole image_2 PNG, as the corri2p-kitti layout's
  `img_P2` (the loader cuts no rows: options.py's `crop_original_top_rows` is read only by
  nuScenes_script/make_dataset.py:263), halved (OpenCV linear) and centre-cropped to 160 x 512
  (kitti_pc_img_dataloader.py:274-287, its val mode), K likewise; its FarthestSampler
  (which uses `np.int`, removed in numpy 1.24) is written out here with the same arithmetic.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import math
import random
import sys
import types
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import torch
from scipy.spatial import cKDTree

from i2pbench.testing.recipe import recipe_value

IMAGE_H, IMAGE_W = 160, 512
NUM_KPT, DIST_THRES, POS_MARGIN, NEG_MARGIN = 512, 1.0, 0.2, 1.8  # train.py defaults


def node_argmax(data: torch.Tensor, owner: torch.Tensor, nodes: int) -> torch.Tensor:
    """CPU stand-in of index_max.forward_cuda_shared_mem: data [B x C x N], owner [B x N] -> [B x C x nodes] int32
    indices of each node's largest value per channel (first on ties; 0 for an empty node)."""
    out = torch.zeros(*data.shape[:2], nodes, dtype=torch.int32)
    for b in range(len(data)):
        for m in range(nodes):
            members = torch.nonzero(owner[b] == m)[:, 0]
            if len(members):
                out[b, :, m] = members[data[b][:, members].argmax(1)].int()
    return out


def import_authors(checkout: Path) -> dict[str, types.ModuleType]:
    """the authors' modules from the checkout, with the two stand-ins installed first."""
    vision = types.ModuleType("torchvision.models.utils")
    vision.load_state_dict_from_url = None
    stand_in = types.ModuleType("index_max")
    stand_in.forward_cuda_shared_mem = node_argmax
    sys.modules.update({"torchvision": types.ModuleType("torchvision"), "index_max": stand_in})
    sys.modules.update(
        {"torchvision.models": types.ModuleType("torchvision.models"), "torchvision.models.utils": vision}
    )
    sys.path.insert(0, str(checkout))
    return {name: importlib.import_module(name) for name in ("options", "network", "loss")}


def read_calib(path: Path) -> dict[str, np.ndarray]:
    rows = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            key, values = line.split(":", 1)
            rows[key.strip()] = np.array(values.split(), np.float64).reshape(3, 4)
    return rows


def camera_from_projection(P: np.ndarray) -> np.ndarray:
    """the loader's KittiCalibHelper: P2 as K [I | t], t from its last column -> the 4x4 translation."""
    K = P[:, :3]
    tz = P[2, 3]
    T = np.eye(4)
    T[:3, 3] = [(P[0, 3] - K[0, 2] * tz) / K[0, 0], (P[1, 3] - K[1, 2] * tz) / K[1, 1], tz]
    return T


def voxel(points: np.ndarray, intensity: np.ndarray, normals: np.ndarray, size: float) -> tuple:
    """the loader's downsample_with_intensity_sn: intensity carried as a colour, normals averaged per voxel."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.T))
    peak = np.max(intensity)
    colours = np.zeros((points.shape[1], 3))
    colours[:, 0] = intensity[0] / peak
    cloud.colors = o3d.utility.Vector3dVector(colours)
    cloud.normals = o3d.utility.Vector3dVector(normals.T)
    down = cloud.voxel_down_sample(voxel_size=size)
    return np.asarray(down.points).T, np.asarray(down.colors)[:, :1].T * peak, np.asarray(down.normals).T


def scan_with_normals(scan: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """kitti_pc_bin_to_npy_with_downsample_sn.py: voxel 0.1 m, normals (radius 0.6, 30 nn, towards +z),
    intensity of the nearest raw point."""
    raw = np.fromfile(scan, np.float32).reshape(-1, 4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(raw[:, :3].astype(np.float64)))
    down = cloud.voxel_down_sample(voxel_size=0.1)
    down.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=0.6, max_nn=30))
    down.orient_normals_to_align_with_direction([0, 0, 1])
    points = np.asarray(down.points)
    _, nearest = cKDTree(raw[:, :3]).query(points, k=1)
    return points.T.astype(np.float32), raw[nearest, 3][None], np.asarray(down.normals).T.astype(np.float32)


def farthest(points: np.ndarray, k: int) -> np.ndarray:
    """the loader's FarthestSampler.sample (numpy, its float64 arithmetic) -> the k nodes [3 x k]."""
    chosen = np.zeros((3, k))
    first = np.random.randint(points.shape[1])
    chosen[:, 0] = points[:, first]
    dist = ((chosen[:, :1] - points) ** 2).sum(axis=0)
    for i in range(1, k):
        chosen[:, i] = points[:, np.argmax(dist)]
        dist = np.minimum(dist, ((chosen[:, i : i + 1] - points) ** 2).sum(axis=0))
    return chosen


def random_motion() -> np.ndarray:
    """train.py's defaults: t uniform in [-10, 10] on x and z, rotation uniform in [-2 pi, 2 pi] about y."""
    t = [random.uniform(-10, 10), random.uniform(-0.0, 0.0), random.uniform(-10, 10)]
    angle = random.uniform(-2 * math.pi, 2 * math.pi)
    c, s = math.cos(angle), math.sin(angle)
    P = np.eye(4, dtype=np.float32)
    P[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    P[:3, 3] = t
    return P


def prepare(frame: Path, index: int, n: int, nodes: int) -> dict[str, np.ndarray]:
    """one frame as kitti_pc_img_dataloader.py's val mode gives it (module docstring), with train.py's anchors."""
    calib = read_calib(frame / "calib.txt")
    points, intensity, normals = scan_with_normals(frame / "velodyne" / f"{index:06d}.bin")
    Tr = np.eye(4)
    Tr[:3] = calib["Tr"]
    P_Tr = camera_from_projection(calib["P2"]) @ Tr
    points = P_Tr[:3, :3] @ points + P_Tr[:3, 3:]
    normals = P_Tr[:3, :3] @ normals
    points, intensity, normals = voxel(points, intensity, normals, 0.1)
    pick = np.random.choice(points.shape[1], n, replace=False)
    points, intensity, normals = points[:, pick], intensity[:, pick], normals[:, pick]
    image = cv2.cvtColor(cv2.imread(str(frame / "image_2" / f"{index:06d}.png")), cv2.COLOR_BGR2RGB)
    K = calib["P2"][:, :3].copy()
    image = cv2.resize(
        image, (round(image.shape[1] * 0.5), round(image.shape[0] * 0.5)), interpolation=cv2.INTER_LINEAR
    )
    K = 0.5 * K
    K[2, 2] = 1
    dx, dy = (image.shape[1] - IMAGE_W) // 2, (image.shape[0] - IMAGE_H) // 2
    image = image[dy : dy + IMAGE_H, dx : dx + IMAGE_W]
    K[0, 2] -= dx
    K[1, 2] -= dy
    K4 = 0.25 * K
    K4[2, 2] = 1
    projected = K4 @ points
    xy = np.floor(projected[:2] / projected[2:])
    h4, w4 = IMAGE_H // 4, IMAGE_W // 4
    seen = (xy[0] >= 0) & (xy[0] <= w4 - 1) & (xy[1] >= 0) & (xy[1] <= h4 - 1) & (projected[2] > 0)
    img_mask = np.zeros((h4, w4))
    img_mask[xy[1, seen].astype(int), xy[0, seen].astype(int)] = 1
    inside = np.where(seen)[0][np.random.permutation(seen.sum())]
    outside = np.where(~seen)[0][np.random.permutation((~seen).sum())]
    img_outside = np.where(img_mask.reshape(-1) == 0)[0]
    img_outside = img_outside[np.random.permutation(len(img_outside))]
    kpt = min(NUM_KPT, len(inside), len(outside), len(img_outside))
    motion = random_motion()
    points = motion[:3, :3] @ points + motion[:3, 3:]
    normals = motion[:3, :3] @ normals
    node_a = farthest(points[:, np.random.choice(n, nodes * 8, replace=False)], nodes)
    node_b = farthest(points[:, np.random.choice(n, nodes * 8, replace=False)], nodes)
    return {
        "image": image, "pc": points.astype(np.float32), "intensity": intensity.astype(np.float32),
        "sn": normals.astype(np.float32), "K": K4.astype(np.float32), "P": np.linalg.inv(motion).astype(np.float32),
        "node_a": node_a.astype(np.float32), "node_b": node_b.astype(np.float32), "pc_kpt_idx": inside[:kpt],
        "pc_outline_idx": outside[:kpt], "img_outline_idx": img_outside[:kpt], "P_Tr": P_Tr.astype(np.float32),
        "img_kpt_idx": (xy[1, inside[:kpt]] * w4 + xy[0, inside[:kpt]]).astype(np.int64),
    }  # fmt: skip


def losses(authors: dict, inputs: dict, out: dict) -> dict[str, np.ndarray]:
    """train.py:236-263 on one frame: circle loss over the anchors, det_loss2, total = desc + 0.5 det."""
    t = {k: torch.from_numpy(np.asarray(v))[None] for k, v in inputs.items() if k != "image"}
    kpt = t["pc_kpt_idx"].shape[1]
    img_f, pc_f, img_s, pc_s = (out[k] for k in ("img_feature", "pc_feature", "img_score", "pc_score"))
    h4, w4 = img_f.shape[2:]
    xs = torch.linspace(0, w4 - 1, w4).view(1, -1).expand(h4, w4)
    ys = torch.linspace(0, h4 - 1, h4).view(-1, 1).expand(h4, w4)
    img_xy = torch.stack([xs, ys])[None].reshape(1, 2, -1)

    def take(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return x.gather(2, idx[:, None].expand(-1, x.shape[1], -1))

    pc_in, pc_sc_in, pc_sc_out = (
        take(pc_f, t["pc_kpt_idx"]),
        take(pc_s, t["pc_kpt_idx"]),
        take(pc_s, t["pc_outline_idx"]),
    )
    xyz_in = take(t["pc"], t["pc_kpt_idx"])
    img_flat, img_s_flat = img_f.reshape(1, img_f.shape[1], -1), img_s.reshape(1, 1, -1)
    img_in, xy_in = take(img_flat, t["img_kpt_idx"]), take(img_xy, t["img_kpt_idx"])
    img_sc_in, img_sc_out = take(img_s_flat, t["img_kpt_idx"]), take(img_s_flat, t["img_outline_idx"])
    projected = torch.bmm(t["K"], torch.bmm(t["P"][:, :3, :3], xyz_in) + t["P"][:, :3, 3:])
    xy = projected[:, :2] / projected[:, 2:]
    mask = (torch.sqrt(((xy_in[..., None] - xy[:, :, None]) ** 2).sum(1)) <= DIST_THRES).float()
    desc, dists = authors["loss"].desc_loss(
        img_in, pc_in, mask, pos_margin=POS_MARGIN, neg_margin=NEG_MARGIN, num_kpt=kpt
    )
    det = authors["loss"].det_loss2(
        img_sc_in.squeeze(), img_sc_out.squeeze(), pc_sc_in.squeeze(), pc_sc_out.squeeze(), dists, mask
    )
    return {"correspondence_mask": mask[0].numpy(), "loss_desc": desc.numpy(), "loss_det": det.numpy(),
            "loss": (desc + 0.5 * det).numpy()}  # fmt: skip


MODULES = {  # authors' module -> recorded name(s) of its output
    "img_32_attention_conv": "image_attention32_logits",
    "img_16_attention_conv": "image_attention16_logits",
    "up_conv1": "up16",
    "up_conv2": "up8",
    "up_conv3": "up4",
    "node_b_attention_pn": "node_b_attention_logits",
    "node_b_pn": "node_b_up",
    "node_a_attention_pn": "node_a_attention_logits",
    "node_a_pn": "node_a_up",
    "per_point_pn": "per_point",
}
ENCODER3D = tuple(
    f"pc_{k}" for k in ("centers", "node_a_mean", "point_node_a", "first", "second", "node_a", "node_b", "global")
)
ENCODER2D = ("img_s2", "img_s4", "img_s8", "img_s16", "img_s32", "img_global")
# the ResNet maps at strides 2 to 8 (4.2 MB of a 6.8 MB set at --n 2048) are left out to keep a set small: the
# decoder's outputs up8 and up4, which read them, are recorded, and tests/data/peer_resnet34 checks the ResNet alone
LEFT_OUT = ("img_s2", "img_s4", "img_s8")


def run(authors: dict, inputs: dict, salt: str) -> tuple[dict, dict, str]:
    """the authors' network with the recipe's weights on the inputs -> (recorded tensors, shapes, weights sha256)."""
    opt = authors["options"].Options()
    opt.input_pt_num = inputs["pc"].shape[1]
    net = authors["network"].CorrI2P(opt).eval()
    digest, state = hashlib.sha256(), {}
    for key, value in net.state_dict().items():
        array = recipe_value(key, tuple(value.shape), salt)
        digest.update(array.astype(array.dtype.newbyteorder("<")).tobytes())
        state[key] = torch.from_numpy(array)
    net.load_state_dict(state)
    record: dict[str, torch.Tensor] = {}

    def keep(name):
        return lambda _module, _args, output: record.__setitem__(name, output)

    for module, name in MODULES.items():
        getattr(net, module).register_forward_hook(keep(name))
    net.pc_encoder.register_forward_hook(lambda _m, _a, out: record.update(zip(ENCODER3D, out, strict=True)))
    net.img_encoder.register_forward_hook(lambda _m, _a, out: record.update(zip(ENCODER2D, out, strict=True)))
    t = {k: torch.from_numpy(inputs[k])[None] for k in ("pc", "intensity", "sn", "node_a", "node_b")}
    image = torch.from_numpy(inputs["image"].astype(np.float32) / 255.0).permute(2, 0, 1)[None].contiguous()
    with torch.no_grad():
        outputs = net(t["pc"], t["intensity"], t["sn"], image, t["node_a"], t["node_b"])
        named = dict(zip(("img_feature", "pc_feature", "img_score", "pc_score"), outputs, strict=True))
        for large in LEFT_OUT:
            record.pop(large)
        record.update(named)
        loss = losses(authors, inputs, named)
    tensors = {k: v[0].numpy() for k, v in record.items()} | loss
    shapes = {k: list(v.shape) for k, v in state.items()}
    return tensors, shapes, digest.hexdigest()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkout", type=Path, help="a checkout of rsy6318/CorrI2P")
    parser.add_argument("--frame", type=Path, required=True, help="a KITTI odometry sequence folder")
    parser.add_argument("--frame-index", type=int, default=0)
    parser.add_argument("--salt", default="")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--n", type=int, default=2048, help="points (the authors' 40,960; fewer keeps a set small)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    authors = import_authors(args.checkout)
    np.random.seed(args.seed)
    random.seed(args.seed)
    torch.manual_seed(args.seed)
    opt = authors["options"].Options()
    inputs = prepare(args.frame, args.frame_index, args.n, opt.node_a_num)
    tensors, shapes, sha = run(authors, inputs, args.salt)
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "inputs.npz", **inputs)
    np.savez_compressed(args.out / "outputs.npz", **tensors)
    (args.out / "state_dict_shapes.json").write_text(json.dumps(shapes, indent=0) + "\n")
    (args.out / "weights.sha256").write_text(sha + "\n")
    commit = (args.checkout / ".git").exists() and __import__("subprocess").run(
        ["git", "-C", str(args.checkout), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    frame = args.frame.resolve()
    meta = {"frame": str(frame.relative_to(frame.parents[2])), "frame_index": args.frame_index, "salt": args.salt,
            "seed": args.seed, "n": args.n, "nodes": opt.node_a_num, "num_kpt": len(inputs["pc_kpt_idx"]),
            "authors_commit": commit or None, "torch": torch.__version__}  # fmt: skip
    (args.out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
