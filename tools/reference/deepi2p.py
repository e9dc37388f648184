"""Reference vectors of DeepI2P's network from its authors' code (lijx10/DeepI2P, MIT), run outside i2pbench.

    python tools/reference/deepi2p.py /path/to/DeepI2P --out DIR [--frame DIR --frame-index ID --salt S --seed N --n N]

Imports `models.networks_united.KeypointDetector` and the loss code of `models/multimodal_classifier.py` from the
checkout, fills the network with the seeded recipe of ../shared/data/edgeregnet_reference/README.md
(`crc32(key + salt)`), prepares one KITTI frame as their `data/kitti_pc_img_pose_loader.py` does in its
`val_random_Ry` mode and writes inputs.npz, outputs.npz, state_dict_shapes.json, weights.sha256, meta.json.

Where their code cannot run here, and what stands in (README.md of the set repeats this):
- `index_max.forward_cuda_shared_mem` (a CUDA extension): a CPU loop returning, per node and channel, the first index
  of the member point holding the maximum;
- `resnet34(pretrained=True)` downloads ImageNet weights: built with `pretrained=False` (the recipe fills it anyway);
- torchvision (imported by multimodal_classifier.py and resnet.py for the download helper, unused with
  `pretrained=False`) is not installed here: empty modules stand in, the helper being torch.hub's, which it wraps;
- `opt.device` is `cuda:1`: set to the CPU; `opt.input_pt_num` is set to `--n` (their 20,480 by default would make a
  set of ~30 MB, 1,024 keeps it near 3 MB; the network's function does not depend on N);
- their loader reads pre-made `voxel0.1-SNr0.6` npy files accumulated over 3 scans with poses and pairs the scan with
  another frame's image: the shared data has neither poses nor those files, so the scan is the frame's own, prepared
  by the same steps (0.1 m voxels, normals of radius 0.6 / 30 neighbours oriented to +z, intensity of the nearest raw
  point; 0.3 m voxels when over 2 N points; a random N) and the image is the same frame's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import types
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import torch

from i2pbench.testing.recipe import recipe_value

FRAME = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti_odometry" / "sequences" / "00"
CAM_FROM_NWU = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], np.float64)


def index_max_cpu(data: torch.Tensor, cluster: torch.Tensor, clusters: int) -> torch.Tensor:
    """CPU stand-in of SO-Net's index_max kernel: [B x C x N], [B x N] -> [B x C x clusters] argmax indices."""
    out = torch.zeros(data.shape[0], data.shape[1], clusters, dtype=torch.int32)
    for b in range(data.shape[0]):
        for m in range(clusters):
            members = torch.nonzero(cluster[b] == m)[:, 0]
            if len(members):
                out[b, :, m] = members[data[b][:, members].argmax(dim=1)].int()
    return out


def import_authors(checkout: Path, n: int):
    """the authors' KeypointDetector, Options and MMClassifer, with the CPU stand-ins in place."""
    sys.path.insert(0, str(checkout))
    sys.modules["index_max"] = types.SimpleNamespace(forward_cuda_shared_mem=index_max_cpu)
    if "torchvision" not in sys.modules:  # imported by their resnet.py / multimodal_classifier.py, not needed here
        utils = types.SimpleNamespace(load_state_dict_from_url=torch.hub.load_state_dict_from_url)
        sys.modules |= {"torchvision": types.ModuleType("torchvision"), "torchvision.models": types.ModuleType("m")}
        sys.modules["torchvision.models.utils"] = utils
    from kitti.options import Options
    from models import multimodal_classifier, networks_united, resnet

    published = resnet.resnet34
    resnet.resnet34 = lambda **kw: published(**{**kw, "pretrained": False})
    opt = Options()
    opt.device, opt.input_pt_num, opt.batch_size = torch.device("cpu"), n, 1
    return networks_united.KeypointDetector(opt), opt, multimodal_classifier


def seeded(model: torch.nn.Module, salt: str) -> tuple[dict[str, list[int]], str]:
    """fill `model` by the recipe; its key shapes in order and the sha256 of the values' bytes."""
    digest, state, shapes = hashlib.sha256(), {}, {}
    for key, value in model.state_dict().items():
        new = recipe_value(key, tuple(value.shape), salt)
        digest.update(new.astype(new.dtype.newbyteorder("<")).tobytes())
        state[key], shapes[key] = torch.from_numpy(new), list(value.shape)
    model.load_state_dict(state)
    return shapes, digest.hexdigest()


def calib(frame: Path) -> tuple[np.ndarray, np.ndarray]:
    """(K of camera 2, Pc: camera 2 <- velodyne as their kitti_helper builds it: P2's offset, then Tr)."""
    rows = {line[:2]: np.array(line[4:].split(), np.float32).reshape(3, 4) for line in open(frame / "calib.txt")}
    K = rows["P2"][:, :3].astype(np.float64)
    tz = rows["P2"][2, 3]
    offset = np.eye(4)
    offset[:3, 3] = [(rows["P2"][0, 3] - K[0, 2] * tz) / K[0, 0], (rows["P2"][1, 3] - K[1, 2] * tz) / K[1, 1], tz]
    tr = np.eye(4)
    tr[:3] = rows["Tr"]
    return K, offset @ tr


def scan(frame: Path, index: str, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """points, intensity, normals [3|1|3 x n] in the velodyne frame, by their preparation + loader steps."""
    raw = np.fromfile(frame / "velodyne" / f"{index}.bin", np.float32).reshape(-1, 4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(raw[:, :3].astype(np.float64)))
    cloud = cloud.voxel_down_sample(0.1)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.6, max_nn=30))
    cloud.orient_normals_to_align_with_direction([0, 0, 1])
    tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(raw[:, :3].astype(np.float64))))
    points = np.asarray(cloud.points)
    nearest = [tree.search_knn_vector_3d(p, 1)[1][0] for p in points]
    pc, intensity, sn = points.T, raw[nearest, 3][None].astype(np.float64), np.asarray(cloud.normals).T
    if pc.shape[1] > 2 * n:
        top = intensity.max()
        coarse = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pc.T))
        coarse.colors = o3d.utility.Vector3dVector(np.c_[intensity.T / top, np.zeros((pc.shape[1], 2))])
        coarse.normals = o3d.utility.Vector3dVector(sn.T)
        coarse = coarse.voxel_down_sample(0.3)
        pc, sn = np.asarray(coarse.points).T, np.asarray(coarse.normals).T
        intensity = np.asarray(coarse.colors)[:, :1].T * top
    pick = rng.choice(pc.shape[1], n, replace=pc.shape[1] < n)
    return (a[:, pick].astype(np.float32) for a in (pc, intensity, sn))


def image(frame: Path, index: str, K: np.ndarray, opt) -> tuple[np.ndarray, np.ndarray]:
    """RGB crop of the top rows, half size, centre crop to H x W; K moved with it (their loader, val modes)."""
    img = cv2.imread(str(frame / "image_2" / f"{index}.png"))[:, :, ::-1][opt.crop_original_top_rows :]
    K = K.copy()
    K[1, 2] -= opt.crop_original_top_rows
    h, w = img.shape[:2]
    img = cv2.resize(img, (round(w * opt.img_scale), round(h * opt.img_scale)), interpolation=cv2.INTER_LINEAR)
    K = K * opt.img_scale
    K[2, 2] = 1
    dx, dy = int((img.shape[1] - opt.img_W) / 2), int((img.shape[0] - opt.img_H) / 2)
    K[0, 2] -= dx
    K[1, 2] -= dy
    return np.ascontiguousarray(img[dy : dy + opt.img_H, dx : dx + opt.img_W]), K


def farthest(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """their FarthestSampler (data/kitti_helper.py): random start, then np.argmax of squared distances (first tie)."""
    chosen = [int(rng.integers(points.shape[1]))]
    distance = ((points - points[:, chosen[0], None]) ** 2).sum(axis=0)
    for _ in range(1, k):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, ((points - points[:, chosen[-1], None]) ** 2).sum(axis=0))
    return points[:, chosen]


def prepare(frame: Path, index: str, opt, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """one sample as their loader's `val_random_Ry` mode returns it (same frame for scan and image)."""
    K, Pc = calib(frame)
    pc, intensity, sn = scan(frame, index, opt.input_pt_num, rng)
    img, K = image(frame, index, K, opt)
    angle = rng.uniform(-2 * np.pi, 2 * np.pi)
    Pr = np.eye(4)
    Pr[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    move = Pr @ CAM_FROM_NWU
    pc = (move[:3, :3] @ pc + move[:3, 3:]).astype(np.float32)
    sn = (move[:3, :3] @ sn).astype(np.float32)
    P = Pc @ np.linalg.inv(CAM_FROM_NWU) @ np.linalg.inv(Pr)
    nodes = [
        farthest(pc[:, rng.choice(pc.shape[1], 8 * m, replace=False)], m, rng) for m in (opt.node_a_num, opt.node_b_num)
    ]
    return {
        "pc": pc, "intensity": intensity, "sn": sn, "node_a": nodes[0].astype(np.float32),
        "node_b": nodes[1].astype(np.float32), "img": img.transpose(2, 0, 1).astype(np.float32),
        "P": P[:3].astype(np.float32), "K": K.astype(np.float32), "Pr": Pr,
    }  # fmt: skip


def record(model: torch.nn.Module) -> tuple[dict[str, torch.Tensor], list]:
    """hooks storing every module output the forward reads, under the names of networks_united.py."""
    seen: dict[str, torch.Tensor] = {}
    names = ("pc_center", "cluster_mean", "node_a_min_k_idx", "first_pn_out", "second_pn_out", "node_a_features",
             "node_b_features", "global_feature")  # fmt: skip
    hooks = [model.pc_encoder.register_forward_hook(lambda m, i, o: seen.update(zip(names, o, strict=True)))]
    image_names = ("img_s16_feature_map", "img_s32_feature_map", "img_global_feature")
    hooks.append(model.img_encoder.register_forward_hook(lambda m, i, o: seen.update(zip(image_names, o, strict=True))))
    heads = {"node_b_attention_pn": "node_b_attention_score", "node_b_pn": "up_node_b_features",
             "node_a_attention_pn": "node_a_attention_score", "node_a_pn": "up_node_a_features",
             }  # fmt: skip
    for module, name in heads.items():
        hooks.append(getattr(model, module).register_forward_hook(lambda m, i, o, name=name: seen.update({name: o})))
    # the attention-weighted image features enter node_b_pn / node_a_pn as input channels 768:1280 / 320:576
    hooks.append(
        model.node_b_pn.register_forward_pre_hook(
            lambda m, i: seen.update({"node_b_weighted_img_s32_feature_map": i[0][:, 768:1280]})
        )
    )
    hooks.append(
        model.node_a_pn.register_forward_pre_hook(
            lambda m, i: seen.update(
                {
                    "interp_ab_weighted_node_b_features": i[0][:, 64:576],
                    "node_a_weighted_img_s16_feature_map": i[0][:, 576:],
                }
            )
        )
    )
    hooks.append(
        model.per_point_pn.register_forward_pre_hook(
            lambda m, i: seen.update(
                {
                    "interp_pa_weighted_node_a_features": i[0][:, :128],
                    "interp_pb_weighted_node_b_features": i[0][:, 128:640],
                }
            )
        )
    )
    return seen, hooks


def losses(classifier_module, model, opt, sample: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """their MMClassifer.foraward_pass (labels by projection, focal coarse loss x 50, fine cross-entropy) on a
    stand-in `self` holding their network, criteria and the sample."""
    host = types.SimpleNamespace(opt=opt, **sample)
    host.forward = lambda *a: model(*a)
    host.coarse_ce_criteria = classifier_module.focal_loss.FocalLoss(alpha=0.5, gamma=2, reduction="mean")
    host.fine_ce_criteria = torch.nn.CrossEntropyLoss()
    loss, _, accuracy = classifier_module.MMClassifer.foraward_pass(host)
    return {f"loss_{k}": v for k, v in loss.items()} | {f"accuracy_{k}": v for k, v in accuracy.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkout", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frame", type=Path, default=FRAME)
    parser.add_argument("--frame-index", default="000000")
    parser.add_argument("--salt", default="")
    parser.add_argument("--seed", type=int, default=20261204)
    parser.add_argument("--n", type=int, default=1024)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    model, opt, classifier_module = import_authors(args.checkout.resolve(), args.n)
    shapes, sha = seeded(model, args.salt)
    model.eval()
    inputs = prepare(args.frame.resolve(), args.frame_index, opt, np.random.default_rng(args.seed))
    batch = {k: torch.from_numpy(v)[None] for k, v in inputs.items() if k != "Pr"}
    seen, hooks = record(model)
    with torch.no_grad():
        coarse, fine = model(*(batch[k] for k in ("pc", "intensity", "sn", "node_a", "node_b", "img")))
        for hook in hooks:
            hook.remove()
        scalars = losses(classifier_module, model, opt, {k: batch[k] for k in batch})
    outputs = {k: v[0].numpy() for k, v in seen.items()} | {
        "coarse_scores": coarse[0].numpy(),
        "fine_scores": fine[0].numpy(),
    }
    outputs |= {k: np.asarray(float(v), np.float32) for k, v in scalars.items()}
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "inputs.npz", **inputs)
    np.savez_compressed(args.out / "outputs.npz", **outputs)
    (args.out / "state_dict_shapes.json").write_text(json.dumps(shapes, indent=1) + "\n")
    (args.out / "weights.sha256").write_text(sha + "\n")
    meta = {"frame": str(args.frame), "frame_index": args.frame_index, "salt": args.salt, "seed": args.seed,
            "n": args.n, "checkout_commit": "cd21389", "mode": "val_random_Ry", "torch": torch.__version__}  # fmt: skip
    (args.out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    main()
