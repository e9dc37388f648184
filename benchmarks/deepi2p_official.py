"""CPU seconds per frame of the official DeepI2P network beside the authors' own KeypointDetector, in one process.

Both get the same recipe weights and the same real KITTI frame prepared at the authors' size (20,480 points, 128 + 128
nodes, 160 x 512 image; tools/reference/deepi2p.py's preparation), eval mode, no grad. The authors' index_max is
the reference tool's CPU loop (their kernel is CUDA-only), ours the scatter max, so the ratio includes that
stand-in. Prints the median of `--repeat` runs after one warm-up, runs interleaved.

    .venv/bin/python benchmarks/deepi2p_official.py /path/to/DeepI2P [--repeat 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
from i2pbench_deepi2p.official.network import DeepI2PNetwork

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools" / "reference"))
import deepi2p as reference  # noqa: E402

ORDER = ("pc", "intensity", "sn", "node_a", "node_b", "img")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkout", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--n", type=int, default=20480)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    authors, opt, _ = reference.import_authors(args.checkout.resolve(), args.n)
    reference.seeded(authors, "")
    ours = DeepI2PNetwork()
    ours.load_state_dict({k: v for k, v in authors.state_dict().items() if ".fc." not in k})
    sample = reference.prepare(reference.FRAME.resolve(), "000000", opt, np.random.default_rng(0))
    batch = [torch.from_numpy(sample[k])[None] for k in ORDER]
    times: dict[str, list[float]] = {"authors": [], "ours": []}
    with torch.no_grad():
        for run in range(args.repeat + 1):
            for name, net in (("authors", authors.eval()), ("ours", ours.eval())):
                start = time.perf_counter()
                net(*batch)
                if run:
                    times[name].append(time.perf_counter() - start)
    median = {k: statistics.median(v) for k, v in times.items()}
    print(f"n={args.n} threads={args.threads}: authors {median['authors']:.3f} s, ours {median['ours']:.3f} s, "
          f"ours/authors {median['ours'] / median['authors']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
