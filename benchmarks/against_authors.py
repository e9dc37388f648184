"""An official method timed beside its authors' own code, stage by stage, alternately in one process.

The authors' network is built from the checkout named on the command line (imported from there, never copied), with
the seeded weights of the method's reference set (its README's recipe) and the same inputs; i2pbench's official size
gets the same weights through its importer. Before timing, both must reproduce the reference set's recorded tensors
(so the two timed networks compute one function). Then, per thread count, `--repeat` rounds each run the authors'
frame and ours, the order swapped every round, each stage timed in wall seconds and in this process's CPU seconds
(on a shared machine the CPU seconds move much less with the neighbours' load, which is recorded with every frame).
Prints per stage the medians and ours / authors'.

    .venv/bin/python benchmarks/against_authors.py --method edgeregnet --checkout /work/peers/EdgeRegNet \
        [--threads 1 2] [--repeat 2] [--keypoints 3000] [--json OUT.json]
    .venv/bin/python benchmarks/against_authors.py --method corri2p --checkout /work/peers/CorrI2P [--points 40960]
    .venv/bin/python benchmarks/against_authors.py --method deepi2p --checkout /work/peers/DeepI2P [--points 20480]
    /tmp/tsvenv/bin/python benchmarks/against_authors.py --method vp2p-match --checkout /work/peers/VP2P-Match \
        [--points 40960]   # an interpreter with torchsparse 2.0 (tools/reference/vp2p.py), this repo's plugins on it
    .venv/bin/python benchmarks/against_authors.py --method cofii2p --checkout /work/peers/CoFiI2P [--points 20480]

A method is one entry of METHODS: a function (checkout, args) -> Pair, the stages both sides split alike, in order.
CorrI2P and DeepI2P are built by their reference tools (tools/reference/*.py, with those tools' CPU stand-in of the
authors' CUDA index_max, so the authors' `points` stage includes a Python loop their GPU would not run) and split as
image encoder, point encoder and the rest (exchange and heads, on the encoders' outputs computed once).
VP2P-Match is built as tools/reference/vp2p.py builds it (torchsparse 2.0 with that tool's CPU stand-ins, so its
interpreter; pointnet2_ops' farthest point sampling and ball query as plain-torch loops, slower than their CUDA
kernels: the authors' `points` stage bounds their code from above) and split as image, point and voxel branches and
the rest (fusion and heads).
CoFiI2P is built as tools/reference/cofii2p.py builds it (einops installed, their open3d.ml KNNSearch stood in for by
their file's own pure-torch knn) and split as the data preparation's point pyramid (their precompute beside
i2pbench.layers.point_pyramid, checked equal), image and point encoders, and the rest of the 'test' forward.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import functools
import importlib.util
import json
import os
import random
import statistics
import sys
import time
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("I2PBENCH_SAMPLE_DATA") or ROOT.parent / "shared" / "data")
Stages = dict[str, Callable[[], object]]  # stage name -> a call running it on inputs computed once


@dataclass
class Pair:
    """the authors' and our stages under common names, in order, and the check that they compute the same."""

    authors: Stages
    ours: Stages
    check: Callable[[], dict[str, float]]  # -> {name: error against the reference}, run before any timing


def load_average() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def time_stages(stages: Stages) -> dict[str, tuple[float, float]]:
    """each stage's (wall s, CPU s of this process), in order."""
    out = {}
    for name, call in stages.items():
        wall, cpu = time.perf_counter(), time.process_time()
        call()
        out[name] = (time.perf_counter() - wall, time.process_time() - cpu)
    return out


def measure(pair: Pair, threads: int, repeat: int) -> dict:
    """`repeat` rounds at `threads` threads, authors' and ours alternately; every frame with the load before it."""
    torch.set_num_threads(threads)
    frames: dict[str, list] = {"authors": [], "ours": []}
    for r in range(repeat):
        order = ("authors", "ours") if r % 2 == 0 else ("ours", "authors")
        for side in order:
            load = load_average()
            with torch.inference_mode():
                times = time_stages(getattr(pair, side))
            frames[side].append({"load": load, "stages": times})
            total = sum(c for _, c in times.values())
            print(f"  {threads} thread(s) round {r + 1} {side:7s} CPU {total:6.2f} s, load {load}", flush=True)
    return frames


def medians(frames: list[dict], column: int) -> dict[str, float]:
    names = list(frames[0]["stages"])
    out = {n: statistics.median(f["stages"][n][column] for f in frames) for n in names}
    out["frame"] = statistics.median(sum(t[column] for t in f["stages"].values()) for f in frames)
    return out


def print_table(threads: int, frames: dict[str, list]) -> dict:
    """per stage: authors' and our median wall and CPU seconds and their ratios; returns the same as a dict."""
    table = {}
    print(f"\n{threads} thread(s), median of {len(frames['ours'])}: seconds (wall / CPU of this process)")
    print(f"{'stage':12s} {'authors':>15s} {'ours':>15s} {'ours/authors':>16s}")
    walls = {side: medians(f, 0) for side, f in frames.items()}
    cpus = {side: medians(f, 1) for side, f in frames.items()}
    for name in walls["ours"]:
        a, o = (walls["authors"][name], cpus["authors"][name]), (walls["ours"][name], cpus["ours"][name])
        ratio = (o[0] / a[0], o[1] / a[1])
        table[name] = {"authors": a, "ours": o, "ratio": ratio}
        print(f"{name:12s} {a[0]:7.2f} {a[1]:7.2f} {o[0]:7.2f} {o[1]:7.2f} {ratio[0]:7.2f}x {ratio[1]:7.2f}x")
    return table


# ---- EdgeRegNet: models/cali_glue.py AttentionModule of ESRSchao/EdgeRegNet


def import_authors_edgeregnet(checkout: Path) -> types.ModuleType:
    """their models.cali_glue, imported from the checkout. It imports torchvision without using it (an empty
    module stands in where torchvision is not installed) and turns on autograd's anomaly detection at import,
    which is turned off again: it would slow our side too."""
    if not (checkout / "models" / "cali_glue.py").is_file():
        raise SystemExit(f"{checkout}: no models/cali_glue.py; --checkout must be an EdgeRegNet checkout")
    try:
        import torchvision  # noqa: F401
    except ImportError:
        sys.modules["torchvision"] = types.SimpleNamespace(models=None)  # type: ignore[assignment]
    sys.path.insert(0, str(checkout))
    try:
        from models import cali_glue
    finally:
        sys.path.remove(str(checkout))
    torch.autograd.set_detect_anomaly(False)
    return cali_glue


def authors_edgeregnet(cali_glue: types.ModuleType, state: dict[str, torch.Tensor]) -> torch.nn.Module:
    """their AttentionModule with `state`. Its SuperPoint loads Magic Leap's file at construction (not in the
    checkout); it is handed the state's own SuperPoint part instead, which load_state_dict sets anyway."""
    superpoint = {k.removeprefix("superpoint."): v for k, v in state.items() if k.startswith("superpoint.")}
    with mock.patch.object(torch, "load", lambda *args, **kwargs: superpoint), mock.patch("builtins.print"):
        model = cali_glue.AttentionModule()
    model.load_state_dict(state)
    return model.eval()


def authors_stages(model: torch.nn.Module, cali_glue: types.ModuleType, inputs: dict[str, np.ndarray]) -> Stages:
    """AttentionModule.forward (cali_glue.py:205-261) cut where ours is: image, points, attention, assignment;
    each stage fed the previous ones' outputs, computed once."""
    xyz = torch.from_numpy(inputs["xyz"])[None]
    image = torch.from_numpy((inputs["canvas"] / 255 - 0.485) / 0.229).float()[None, None]
    kp3d = torch.from_numpy(inputs["kp3d"]).float()[None].permute(0, 2, 1)
    kp2d = torch.from_numpy(inputs["kp2d"].astype(np.float32))[None]

    def image_stage():
        return torch.stack(model.superpoint(image, kp2d)[2])

    def point_stage():
        l1_xyz, l1_points = model.sa1(xyz.permute(0, 2, 1)[:, :3], xyz.permute(0, 2, 1))
        l2_xyz, l2_points = model.sa2(l1_xyz, l1_points)
        return model.fp(kp3d[:, :3], l2_xyz, kp3d, l2_points)

    des2d, des3d = image_stage(), point_stage()

    def attention_stage(d3=des3d, d2=des2d):
        h, w = image.shape[2:]
        d3 = d3 + model.kenc3d(kp3d[:, :3])
        d2 = d2 + model.kenc2d(cali_glue.normalize_coords(kp2d, w, h))
        return model.gnn(d3, d2)

    g3, g2 = attention_stage()

    def assignment_stage():
        des3d, des2d = model.feature_layer(g3), model.feature_layer(g2)
        fov = model.pc_score_layer(g3)
        scores = model.log_assignment(des3d.transpose(1, 2), des2d.transpose(1, 2))[0]
        return cali_glue.filter_matches(scores, 0.0), fov

    stages = {"image": image_stage, "points": point_stage, "attention": attention_stage}
    return stages | {"assignment": assignment_stage}


def our_edgeregnet(state: dict[str, torch.Tensor]) -> dict[str, torch.nn.Module]:
    """the official size's four stages with the authors' state imported (i2pbench's own importer)."""
    from i2pbench_edgeregnet.method import official_stages
    from i2pbench_edgeregnet.official import importer

    split, _ = importer.split(state)
    stages = official_stages()
    for kind, module in stages.items():
        module.load_state_dict(split[kind])
        module.eval()
    return stages


def with_keypoints(inputs: dict[str, np.ndarray], n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """the reference inputs with n keypoints a side (0: the recorded ones): 3D ones drawn from the recorded cloud,
    2D ones uniform over the image pasted on the canvas (the cost depends on the count, not on which)."""
    if n == 0:
        return inputs
    rng = np.random.default_rng(seed)
    rows = np.flatnonzero(inputs["canvas"].any(1))
    cols = np.flatnonzero(inputs["canvas"].any(0))
    uv = np.c_[rng.integers(0, cols.max() + 1, n), rng.integers(0, rows.max() + 1, n)].astype(np.int16)
    kp3d = inputs["xyz"][rng.choice(len(inputs["xyz"]), n, replace=False)]
    return inputs | {"kp3d": kp3d, "kp2d": uv}


def relative(ours: torch.Tensor, ref: np.ndarray) -> float:
    """max |ours - ref| / max |ref| (the reference tests' measure)."""
    return float(np.abs(ours.numpy().astype(np.float64) - ref).max() / np.abs(ref).max())


def edgeregnet_check(authors: Stages, ours: dict, inputs: dict, outputs: dict) -> dict[str, float]:
    """both exchangers on the recorded descriptors against the recorded GNN outputs."""
    from i2pbench_edgeregnet.official.reference import reference_frame

    d3, d2 = (torch.from_numpy(outputs[k])[None] for k in ("des3d_fp", "des2d_superpoint"))
    frame, kp2d, kp3d = reference_frame(inputs)
    exchanger = ours["exchanger"]
    with torch.inference_mode():
        a3, a2 = authors["attention"](d3, d2)
        positions = {k: v[None] for k, v in exchanger.prepare(frame, kp2d, kp3d).items()}
        o2, o3 = exchanger.forward(positions, d2.transpose(1, 2), d3.transpose(1, 2))
    return {
        "authors gnn3d": relative(a3[0], outputs["gnn3d"]),
        "authors gnn2d": relative(a2[0], outputs["gnn2d"]),
        "ours gnn3d": relative(o3[0].T, outputs["gnn3d"]),
        "ours gnn2d": relative(o2[0].T, outputs["gnn2d"]),
    }


def edgeregnet(checkout: Path, args: argparse.Namespace) -> Pair:
    """EdgeRegNet's official size against AttentionModule, on the reference set's frame and weights."""
    from edgeregnet_official import stage_runs  # this folder is on sys.path when the script runs
    from i2pbench_edgeregnet.official.reference import reference_frame

    from i2pbench.testing.recipe import folder_state

    folder = Path(args.reference or os.environ.get("I2PBENCH_EDGEREGNET_REFERENCE", DATA / "edgeregnet_reference"))
    state, digest = folder_state(folder)
    if digest != (folder / "weights.sha256").read_text().split()[0]:
        raise SystemExit(f"{folder}: the regenerated weights do not match weights.sha256")
    cali_glue = import_authors_edgeregnet(checkout)
    model, ours = authors_edgeregnet(cali_glue, state), our_edgeregnet(state)
    recorded, outputs = dict(np.load(folder / "inputs.npz")), dict(np.load(folder / "outputs.npz"))
    with torch.inference_mode():
        check = functools.partial(edgeregnet_check, authors_stages(model, cali_glue, recorded), ours, recorded, outputs)
        inputs = with_keypoints(recorded, args.keypoints)
        authors = authors_stages(model, cali_glue, inputs)
        runs = stage_runs(ours, *reference_frame(inputs))
    renamed = dict(zip(authors, runs.values(), strict=True))  # encoder2d -> image, ... in the same order
    return Pair(authors, renamed, check)


# ---- CorrI2P and DeepI2P: the same SO-Net / ResNet-34 layout, split where both forwards call their encoders


class Recorded(torch.nn.Module):
    """an encoder's output computed once, standing in for the encoder while the rest of the forward is timed
    (a shallow copy each call: a forward may add keys to the dict it gets)."""

    def __init__(self, output: object) -> None:
        super().__init__()
        self.output = output

    def forward(self, *_: object) -> object:
        return copy.copy(self.output)


@contextlib.contextmanager
def encoders_replaced(net: torch.nn.Module, outputs: dict[str, object]):
    """net with the named submodules answering `outputs` while inside; the modules are given back on leaving."""
    kept = {name: getattr(net, name) for name in outputs}
    for name, output in outputs.items():
        setattr(net, name, Recorded(output))
    try:
        yield
    finally:
        for name, module in kept.items():
            setattr(net, name, module)


def encoder_split(
    net: torch.nn.Module, encoders: tuple[str, str], image: tuple, points: tuple, forward: tuple
) -> Stages:
    """net's forward as image encoder, point encoder, and the rest (`exchange`: the exchange between the two and the
    heads) with the named encoders (image, points) replaced by their outputs, computed here once."""
    image_encoder, point_encoder = (getattr(net, name) for name in encoders)
    with torch.inference_mode():
        recorded = dict(zip(encoders, (image_encoder(*image), point_encoder(*points)), strict=True))

    def exchange():
        with encoders_replaced(net, recorded):
            return net(*forward)

    return {"image": lambda: image_encoder(*image), "points": lambda: point_encoder(*points), "exchange": exchange}


def final_errors(sides: dict[str, Stages], named: dict[str, Callable], outputs: dict[str, np.ndarray]) -> dict:
    """each side's split forward (its last stage, the rest of the forward) on the reference inputs: its outputs
    (named by `named[side]`) against the recorded."""
    errors = {}
    with torch.inference_mode():
        for side, stages in sides.items():
            for name, tensor in named[side](list(stages.values())[-1]()).items():
                errors[f"{side} {name}"] = relative(tensor[0], outputs[name])
    return errors


def reference_tool(name: str) -> types.ModuleType:
    """tools/reference/<name>.py, the script that built the method's reference set from the authors' code."""
    spec = importlib.util.spec_from_file_location(f"reference_{name}", ROOT / "tools" / "reference" / f"{name}.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def reference_set(folder: Path) -> tuple[dict, dict[str, np.ndarray], dict[str, np.ndarray]]:
    meta = json.loads((folder / "meta.json").read_text())
    with np.load(folder / "inputs.npz") as inputs, np.load(folder / "outputs.npz") as outputs:
        return meta, dict(inputs), dict(outputs)


def require(checkout: Path, file: str, method: str) -> None:
    if not (checkout / file).is_file():
        raise SystemExit(f"{checkout}: no {file}; --checkout must be a {method} checkout")


def corri2p(checkout: Path, args: argparse.Namespace) -> Pair:
    """CorrI2P's official size against the authors' CorrI2P network (network.py), the reference set's recipe
    weights; timed on the set's frame prepared by the reference tool at `--points` (0: options.py's 40,960)."""
    from i2pbench_corri2p.official.checkpoint import dropped, ours
    from i2pbench_corri2p.official.network import CorrI2PNet
    from i2pbench_corri2p.official.reference import NETWORK_INPUTS, image_tensor

    from i2pbench.testing.recipe import recipe_value

    require(checkout, "network.py", "CorrI2P")
    tool, folder = reference_tool("corri2p"), Path(args.reference or ROOT / "tests/data/reference/corri2p")
    meta, recorded, outputs = reference_set(folder)
    shapes = json.loads((folder / "state_dict_shapes.json").read_text())
    state = {k: torch.from_numpy(recipe_value(k, tuple(s), meta["salt"])) for k, s in shapes.items()}
    authors = tool.import_authors(checkout)
    mine = CorrI2PNet(meta["nodes"], tuple(recorded["image"].shape[:2])).eval()
    mine.load_state_dict({ours(k): v for k, v in state.items() if not dropped(k)})

    def sides(inputs: dict[str, np.ndarray]) -> dict[str, Stages]:
        opt = authors["options"].Options()
        opt.input_pt_num = inputs["pc"].shape[1]  # their encoder's node mask is built for that many points
        theirs = authors["network"].CorrI2P(opt).eval()
        theirs.load_state_dict(state)
        t = {k: torch.from_numpy(inputs[k])[None] for k in NETWORK_INPUTS}
        image = image_tensor(inputs["image"])
        points = (t["pc"], t["intensity"], t["sn"], t["node_a"], t["node_b"])
        forward = (*points[:3], image, *points[3:])
        return {
            "authors": encoder_split(theirs, ("img_encoder", "pc_encoder"), (image,), points, forward),
            "ours": encoder_split(mine, ("encoder2d", "encoder3d"), (image,), points, forward),
        }

    names = ("img_feature", "pc_feature", "img_score", "pc_score")
    named = {"authors": lambda out: dict(zip(names, out, strict=True)), "ours": lambda out: {k: out[k] for k in names}}
    check = functools.partial(final_errors, sides(recorded), named, {k: outputs[k] for k in names})
    n = args.points or authors["options"].Options().input_pt_num
    np.random.seed(meta["seed"])  # the tool's own seeding, as its main() does
    random.seed(meta["seed"])
    inputs = tool.prepare(DATA / meta["frame"], meta["frame_index"], n, meta["nodes"])
    timed = sides(inputs)
    return Pair(timed["authors"], timed["ours"], check)


def deepi2p(checkout: Path, args: argparse.Namespace) -> Pair:
    """DeepI2P's official size against the authors' KeypointDetector (models/networks_united.py), the reference
    set's recipe weights; timed on the set's frame prepared by the reference tool at `--points` (0: their 20,480)."""
    from i2pbench_deepi2p.official.network import DeepI2PNetwork
    from i2pbench_deepi2p.official.reference import INPUTS
    from i2pbench_deepi2p.official.weights import to_network

    require(checkout, "models/networks_united.py", "DeepI2P")
    tool, folder = reference_tool("deepi2p"), Path(args.reference or ROOT / "tests/data/reference/deepi2p")
    meta, recorded, outputs = reference_set(folder)

    def authors_network(n: int) -> tuple[torch.nn.Module, object]:
        model, opt, _ = tool.import_authors(checkout, n)  # their encoder's node mask is built for n points
        _, digest = tool.seeded(model, meta["salt"])
        if digest != (folder / "weights.sha256").read_text().split()[0]:
            raise SystemExit(f"{folder}: the regenerated weights do not match weights.sha256")
        return model.eval(), opt

    theirs, _ = authors_network(meta["n"])
    mine = DeepI2PNetwork(tuple(recorded["img"].shape[1:]))
    mine.load_state_dict(to_network(theirs.state_dict(), mine.state_dict(), f"{folder} (regenerated)"))
    mine.eval()

    def sides(net: torch.nn.Module, inputs: dict[str, np.ndarray]) -> dict[str, Stages]:
        batch = tuple(torch.from_numpy(inputs[k])[None] for k in INPUTS)
        split = functools.partial(
            encoder_split, encoders=("img_encoder", "pc_encoder"), image=batch[5:], points=batch[:5], forward=batch
        )
        return {"authors": split(net), "ours": split(mine)}

    names = ("coarse_scores", "fine_scores")
    named = {"authors": lambda out: dict(zip(names, out, strict=True)), "ours": lambda out: {k: out[k] for k in names}}
    check = functools.partial(final_errors, sides(theirs, recorded), named, {k: outputs[k] for k in names})
    n = args.points or sys.modules["kitti.options"].Options().input_pt_num
    big, opt = authors_network(n)
    inputs = tool.prepare(DATA / meta["frame"], meta["frame_index"], opt, np.random.default_rng(meta["seed"]))
    timed = sides(big, inputs)
    return Pair(timed["authors"], timed["ours"], check)


# ---- VP2P-Match: models/triplet_network.py VP2PMatchNet, three branches then fusion and heads


@contextlib.contextmanager
def cuda_on_cpu():
    """Tensor.cuda a no-op while inside: their forward puts its batch indices on the GPU (triplet_network.py:59)."""
    cuda = torch.Tensor.cuda
    torch.Tensor.cuda = lambda self, *args, **kwargs: self
    try:
        yield
    finally:
        torch.Tensor.cuda = cuda


def import_authors_vp2p(checkout: Path, tool: types.ModuleType) -> tuple[type, type]:
    """their VP2PMatchNet and Options classes from the checkout, on torchsparse 2.0 with the reference tool's CPU
    stand-ins (its sparse convolutions, pointnet2_ops' CUDA kernels); refused by name where torchsparse is missing."""
    require(checkout, "models/triplet_network.py", "VP2P-Match")
    if importlib.util.find_spec("torchsparse") is None:
        raise SystemExit(
            f"VP2P-Match's authors' code needs torchsparse 2.0 (their voxel branch), which {sys.executable} cannot "
            "import: run this with the interpreter that has it, as tools/reference/vp2p.py is run"
        )
    tool.load_sibling("sparse").add_cpu_stand_ins()
    tool.load_sibling("pointnet2_cpu").install()
    sys.path.insert(0, str(checkout))
    try:
        from models.triplet_network import VP2PMatchNet
        from utils.options import Options
    finally:
        sys.path.remove(str(checkout))
    return VP2PMatchNet, Options


def vp2p_match(checkout: Path, args: argparse.Namespace) -> Pair:
    """VP2P-Match's official size against the authors' VP2PMatchNet, the reference set's recipe weights; split as
    image, point and voxel branches and the rest (fusion and heads); timed on the set's frame prepared by the
    reference tool at `--points` (0: their 40,960) and their 160 x 512 image."""
    from i2pbench_vp2p_match.official.network import VP2PMatchNet
    from i2pbench_vp2p_match.official.spvcnn import voxel_coordinates

    from i2pbench.testing.recipe import recipe_state

    tool, folder = reference_tool("vp2p"), Path(args.reference or ROOT / "tests/data/vp2p_reference")
    authors_class, options = import_authors_vp2p(checkout, tool)
    meta, recorded, outputs = reference_set(folder)
    shapes = json.loads((folder / "state_dict_shapes.json").read_text())
    state, digest = recipe_state(shapes, meta["salt"])
    if digest != (folder / "weights.sha256").read_text().split()[0]:
        raise SystemExit(f"{folder}: the regenerated weights do not match weights.sha256")
    with mock.patch("builtins.print"):
        theirs = authors_class(options())
    theirs.load_state_dict(state)
    mine = VP2PMatchNet()
    mine.load_state_dict(state)
    nets = {"authors": theirs.eval(), "ours": mine.eval()}

    def split(net: torch.nn.Module, inputs: dict[str, np.ndarray]) -> Stages:
        pc, intensity, sn, img = (torch.from_numpy(inputs[k])[None] for k in ("pc", "intensity", "sn", "img"))
        cloud = torch.cat([pc, intensity, sn], dim=1)
        branches = {
            "resnet": (net.resnet, (img,)),
            "point_transformer": (net.point_transformer, (cloud,)),
            "voxel_branch": (net.voxel_branch, (cloud.transpose(2, 1).reshape(-1, 7), voxel_coordinates(pc), 1)),
        }
        with torch.inference_mode():
            once = {name: module(*call) for name, (module, call) in branches.items()}

        def run(module: torch.nn.Module, call: tuple) -> Callable[[], object]:
            return lambda: module(*call)

        def fusion():
            with encoders_replaced(net, once), cuda_on_cpu():
                return net(pc, intensity, sn, img)

        stages = dict(zip(("image", "points", "voxels"), (run(*b) for b in branches.values()), strict=True))
        return stages | {"fusion": fusion}

    names = ("pixel_feat", "point_feat", "img_score", "pc_score")
    named = dict.fromkeys(nets, lambda out: dict(zip(names, out, strict=True)))
    references = {k: outputs[f"network.{k}"] for k in names}
    check = functools.partial(final_errors, {s: split(n, recorded) for s, n in nets.items()}, named, references)
    frame = DATA / "kitti_odometry" / meta["frame"]
    opt = options()
    inputs = tool.frame_points(frame, meta["frame_index"], args.points or opt.input_pt_num, meta["seed"])
    inputs["img"] = tool.frame_image(frame, meta["frame_index"], (opt.img_H, opt.img_W))
    return Pair(split(theirs, inputs), split(mine, inputs), check)


# ---- CoFiI2P: model/network.py CoFiI2P, its data preparation (the KPConv pyramid) timed beside it


def recorded_outputs(tensors: dict[str, torch.Tensor], meta: dict) -> dict[str, np.ndarray]:
    """tensors as a reference set keeps them: those it sampled as every step-th flat value."""
    out = {}
    for name, tensor in tensors.items():
        array = tensor.numpy()
        how = meta.get("sampled", {}).get(name)
        out[name] = array.reshape(-1)[:: how["step"]] if how and list(array.shape) == how["shape"] else array
    return out


def pyramid_errors(theirs: dict, ours: dict) -> dict[str, float]:
    """ours against theirs: 0 where the two pyramids' points and neighbour lists are equal, inf where not."""
    keys = ("points", "neighbors", "subsampling", "upsampling")
    same = all(torch.equal(a, b.to(a.dtype)) for k in keys for a, b in zip(ours[k], theirs[k], strict=True))
    return {"ours pyramid": 0.0 if same else float("inf")}


def cofii2p(checkout: Path, args: argparse.Namespace) -> Pair:
    """CoFiI2P's official size against the authors' CoFiI2P (model/network.py) built by tools/reference/cofii2p.py
    (their open3d.ml KNNSearch stood in for by their own knn, .cuda a no-op), the reference set's recipe weights and
    kernel dispositions; split as the pyramid (preprocess_data.py's halvings and kNN-128, theirs beside
    i2pbench.layers.point_pyramid), image and point encoders, and the rest of the forward in 'test' mode (transformer,
    heads, selection, patches); timed on the set's frame prepared by the tool at `--points` (0: their 20,480)."""
    import atexit
    import shutil
    import tempfile

    from i2pbench_cofii2p.official.importer import split
    from i2pbench_cofii2p.official.network import CoFiI2PNetwork
    from i2pbench_cofii2p.official.reference import NETWORK_OUTPUTS, image_tensor, pyramid

    from i2pbench.layers.point_pyramid import point_pyramid
    from i2pbench.testing.recipe import folder_state

    require(checkout, "model/network.py", "CoFiI2P")
    tool, folder = reference_tool("cofii2p"), Path(args.reference or ROOT / "tests/data/reference/cofii2p")
    meta, recorded, outputs = reference_set(folder)
    learned, digest = folder_state(folder)
    if digest != (folder / "weights.sha256").read_text().split()[0]:
        raise SystemExit(f"{folder}: the regenerated weights do not match weights.sha256")
    state = learned | {k: torch.from_numpy(v) for k, v in recorded.items() if k.endswith("kernel_points")}
    scratch = tempfile.mkdtemp(prefix="cofii2p-kernels-")  # their kernel_points.py writes its file there
    atexit.register(shutil.rmtree, scratch, True)
    authors = tool.import_authors(checkout, Path(scratch))
    with mock.patch("builtins.print"):
        theirs = authors["network"].CoFiI2P(authors["options"].Options_KITTI())
    theirs.load_state_dict(state)
    mine = CoFiI2PNetwork()
    mine.load_state_dict({k.removeprefix("net."): v for k, v in split(state)[0].items()})
    nets = {"authors": theirs.eval(), "ours": mine.eval()}

    def forward_split(net: torch.nn.Module, data: dict, image: torch.Tensor) -> Stages:
        test = (data, image, None, None, None, "test")
        return encoder_split(net, ("img_encoder", "pc_encoder"), (image,), (data,), test)

    def check() -> dict[str, float]:
        data, image = pyramid(recorded), image_tensor(recorded["image"])
        errors = {}
        with torch.inference_mode():
            for side, net in nets.items():
                got = recorded_outputs(dict(zip(NETWORK_OUTPUTS, net(*(data, image, None, None, None, "test")),
                                                strict=True)), meta)  # fmt: skip
                for name in ("img_feature_norm", "pc_feature_norm", "coarse_pc_score", "fine_img_feature_patch"):
                    errors[f"{side} {name}"] = relative(torch.from_numpy(got[name]), outputs[name])
        return errors | pyramid_errors(theirs_pyramid(), ours_pyramid())

    n = args.points or authors["options"].Options_KITTI().num_pc
    np.random.seed(meta["seed"])  # the tool's own seeding, as its main() does
    random.seed(meta["seed"])
    torch.manual_seed(meta["seed"])
    data, inputs = tool.prepare(authors, DATA / meta["frame"], meta["frame_index"], n)
    cloud = data["points"][0].numpy()

    def theirs_pyramid() -> dict:
        np.random.seed(meta["seed"])
        return authors["preprocess"].precompute_point_cloud_stack_mode(cloud.T, None, None, len(cloud), 5)

    def ours_pyramid() -> dict:
        return point_pyramid(cloud, np.random.RandomState(meta["seed"])).as_inputs(data["feats"])

    image = image_tensor(inputs["image"])
    sides = {side: {"pyramid": build} | forward_split(net, data, image)
             for (side, net), build in zip(nets.items(), (theirs_pyramid, ours_pyramid), strict=True)}  # fmt: skip
    return Pair(sides["authors"], sides["ours"], check)


METHODS: dict[str, Callable[[Path, argparse.Namespace], Pair]] = {
    "edgeregnet": edgeregnet,
    "corri2p": corri2p,
    "deepi2p": deepi2p,
    "vp2p-match": vp2p_match,
    "cofii2p": cofii2p,
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", required=True, choices=sorted(METHODS))
    parser.add_argument("--checkout", required=True, type=Path, help="the authors' code, e.g. /work/peers/EdgeRegNet")
    parser.add_argument("--reference", help="the method's reference set (default: its set in the repo or shared data)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--keypoints", type=int, default=3000, help="EdgeRegNet, a side; 0: the reference set's own")
    parser.add_argument("--points", type=int, default=0, help="CorrI2P, DeepI2P, VP2P-Match, CoFiI2P: cloud; 0: the "
                        "authors'")  # fmt: skip
    parser.add_argument("--json", type=Path, help="write every frame's times and load here")
    args = parser.parse_args(argv)
    print(f"torch {torch.__version__}; load {load_average()}; building {args.method} from {args.checkout}", flush=True)
    pair = METHODS[args.method](args.checkout.resolve(), args)
    errors = pair.check()
    print("check against the reference set (max error / max |ref|, bound 1e-4): " + ", ".join(
        f"{k} {v:.1e}" for k, v in errors.items()))  # fmt: skip
    if any(v > 1e-4 for v in errors.values()):
        print("the two sides do not compute the reference function: not timed", file=sys.stderr)
        return 1
    report = {"method": args.method, "keypoints": args.keypoints, "points": args.points, "check": errors, "threads": {}}
    for threads in args.threads:
        frames = measure(pair, threads, args.repeat)
        report["threads"][threads] = {"frames": frames, "table": print_table(threads, frames)}
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
