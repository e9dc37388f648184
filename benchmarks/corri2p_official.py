"""Seconds per frame of CorrI2P's official network beside its authors' code on this CPU, in one process, run
alternately (ours, theirs, ours, ...) on the same inputs and the same seeded weights, and both parameter counts.

The inputs are a reference folder made by tools/reference/corri2p.py (its `--n` sets the cloud: the authors train
and test on 40,960 points, so make one with `--n 40960` to time their size). The authors' network is imported from
the checkout given (with the CPU stand-ins of the reference script); neither side's data preparation is timed.

    .venv/bin/python benchmarks/corri2p_official.py /work/peers/CorrI2P tests/data/reference/corri2p \
        [--repeat 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from i2pbench_corri2p.official.checkpoint import dropped, ours
from i2pbench_corri2p.official.network import CorrI2PNet
from i2pbench_corri2p.official.reference import NETWORK_INPUTS, image_tensor
from i2pbench_edgeregnet.reference import recipe_value

TOOL = Path(__file__).resolve().parents[1] / "tools" / "reference" / "corri2p.py"


def authors_network(checkout: Path, folder: Path, state: dict[str, torch.Tensor]) -> torch.nn.Module:
    spec = importlib.util.spec_from_file_location("corri2p_reference_tool", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    authors = tool.import_authors(checkout)
    opt = authors["options"].Options()
    opt.input_pt_num = int(json.loads((folder / "meta.json").read_text())["n"])
    net = authors["network"].CorrI2P(opt).eval()
    net.load_state_dict(state)
    return net


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkout", type=Path)
    parser.add_argument("folder", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    shapes = json.loads((args.folder / "state_dict_shapes.json").read_text())
    salt = json.loads((args.folder / "meta.json").read_text())["salt"]
    state = {k: torch.from_numpy(recipe_value(k, tuple(s), salt)) for k, s in shapes.items()}
    theirs = authors_network(args.checkout, args.folder, state)
    mine = CorrI2PNet().eval()
    mine.load_state_dict({ours(k): v for k, v in state.items() if not dropped(k)})
    with np.load(args.folder / "inputs.npz") as data:
        inputs = dict(data)
    t = {k: torch.from_numpy(inputs[k])[None] for k in NETWORK_INPUTS}
    call = (t["pc"], t["intensity"], t["sn"], image_tensor(inputs["image"]), t["node_a"], t["node_b"])
    seconds: dict[str, list[float]] = {"ours": [], "authors'": []}
    with torch.no_grad():
        for net in (mine, theirs):  # warm-up
            net(*call)
        for _ in range(args.repeat):
            for name, net in (("ours", mine), ("authors'", theirs)):
                start = time.perf_counter()
                net(*call)
                seconds[name].append(time.perf_counter() - start)
    counts = {
        "ours": sum(p.numel() for p in mine.parameters()),
        "authors'": sum(p.numel() for p in theirs.parameters()),
    }
    print(f"{len(inputs['pc'][0])} points, {args.threads} thread(s), median of {args.repeat}, alternating")
    for name in seconds:
        print(f"{name:9s} {statistics.median(seconds[name]):7.3f} s/frame  {counts[name]:,} parameters")
    ratio = statistics.median(seconds["ours"]) / statistics.median(seconds["authors'"])
    print(f"ours / authors' time: {ratio:.2f}")


if __name__ == "__main__":
    main()
