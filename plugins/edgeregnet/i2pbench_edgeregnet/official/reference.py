"""Reference vectors of the authors' network (a folder made by their `AttentionModule`, see its README.md): the
official size's forward on the recorded inputs returning every tensor the folder records, under the folder's names
and layouts (channels first, rows 3D), with the weights of `i2pbench.testing.recipe`. tests/test_edgeregnet_reference.py
compares them; benchmarks/edgeregnet_official.py times the same forward.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from i2pbench.api import Frame, Keypoints2D, Keypoints3D

from .matching import filter_matches


def reference_frame(inputs: dict[str, np.ndarray]) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    """the recorded frame in metres (the cloud and edge points un-normalised), grey canvas as its image."""
    nc, md = inputs["nc"].astype(np.float64), float(inputs["md"])
    points = inputs["xyz"].astype(np.float64)
    points[:, :3] = points[:, :3] * md + nc
    edges = inputs["kp3d"].astype(np.float64)
    xyz = edges[:, :3] * md + nc
    T = np.vstack([inputs["Tr"], [0, 0, 0, 1]]) @ np.linalg.inv(inputs["T_rand"])
    n = len(points)
    frame = Frame(
        "reference", "0", np.repeat(inputs["canvas"][..., None], 3, 2), points.astype(np.float32),
        np.zeros(n, np.int16), np.linalg.norm(points[:, :3], axis=1).astype(np.float32), inputs["P2"][:, :3], T,
    )  # fmt: skip
    kp3d = Keypoints3D(np.arange(len(xyz)), xyz.astype(np.float32), edges[:, 3].astype(np.float32))
    return frame, Keypoints2D(inputs["kp2d"].astype(np.float32)), kp3d


@torch.no_grad()
def reference_forward(stages: dict, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the official stages (eval mode) on the recorded inputs -> every recorded tensor, by the folder's names.

    The 2D branch and the exchanger run from a frame through their `prepare` (canvas, normalisations); the 3D
    branch takes the recorded normalised cloud and the recorded FPS draws, as the authors' forward did."""
    frame, kp2d, kp3d = reference_frame(inputs)
    enc2d, enc3d, exchanger, matcher = (stages[k] for k in ("encoder2d", "encoder3d", "exchanger", "matcher"))
    d2 = enc2d.batched(enc2d.one(frame, kp2d))
    xyz = torch.from_numpy(inputs["xyz"])
    fps = (torch.from_numpy(inputs["fps_sa1"]), torch.from_numpy(inputs["fps_sa2"]))
    grouped = {"xyz": xyz, "edges": torch.from_numpy(inputs["kp3d"]), **enc3d.group(xyz, fps=fps)}
    sa: dict = {}
    d3 = enc3d.forward({k: v[None] for k, v in grouped.items()}, trace=sa)
    enc: dict = {}
    positions = {k: v[None] for k, v in exchanger.prepare(frame, kp2d, kp3d).items()}
    g2, g3 = exchanger.forward(positions, d2, d3, trace=enc)
    out = {k: v[0] for k, v in matcher.forward(g2, g3).items()}
    i3d, i2d, _ = filter_matches(out["log_assignment"], matcher.conf["filter_threshold"])
    first = {"des2d_superpoint": d2, "sa1_points": sa["sa1"], "sa2_points": sa["sa2"], "des3d_fp": d3}
    first |= {"enc3d": enc["enc3d"], "enc2d": enc["enc2d"], "gnn3d": g3, "gnn2d": g2}
    tensors = {k: v[0].T for k, v in first.items()} | {"des3d": out["des3d"].T, "des2d": out["des2d"].T}
    tensors |= {"fov": torch.sigmoid(out["fov"]), "sim": out["sim"], "log_assignment": out["log_assignment"]}
    tensors |= {"logsig3d": F.logsigmoid(out["z3d"]), "logsig2d": F.logsigmoid(out["z2d"])}
    tensors |= {"matches": torch.stack([i3d, i2d], 1), "z3d": out["z3d"], "z2d": out["z2d"]}
    tensors["fov_logits"] = out["fov"]
    return {k: v.numpy() for k, v in tensors.items()}
