"""`i2pbench viz`: one frame's LiDAR points projected under the initial, ground-truth and predicted poses, as PNG."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from .options import (
    DEVICE_HELP,
    add_conf_option,
    add_data_options,
    add_stage_options,
    chosen_combinations,
    open_dataset,
)

if TYPE_CHECKING:
    import numpy as np


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("viz", help="draw one frame's LiDAR points under the initial, ground-truth and predicted poses")
    p.add_argument("frame", help="frame id (e.g. 00/000000) or its index in the split (e.g. 0)")
    add_stage_options(p, "{kind} name; 'none' skips")
    p.add_argument("--preset", help="a registered preset; it must come down to one combination with the options")
    add_conf_option(p)
    add_data_options(p)
    p.add_argument("--weights", default="auto", help="'auto', 'untrained', or a checkpoint path")
    p.add_argument("--device", default="auto", help=DEVICE_HELP)
    p.add_argument("--seed", type=int, default=0, help="protocol seed for the random transform")
    p.add_argument("--out", help="PNG path (default viz/<dataset>-<split>-<frame>.png)")
    p.add_argument("--edges", action="store_true", help="add a panel of the 2D and 3D edge points")
    p.add_argument("--matches", action="store_true", help="add a panel of the matches, inliers vs outliers")
    p.add_argument("--radius", type=int, default=1, help="point radius in pixels (0: one pixel)")
    p.set_defaults(grid=None)


def resolve_frame(frame_ids: list[str], frame: str) -> str:
    """A frame id as given, or the id at that index when FRAME is a bare number not itself an id."""
    from ..errors import DataError

    if frame in frame_ids or not frame.isdigit():
        return frame
    if int(frame) >= len(frame_ids):
        raise DataError(f"frame index {frame} is past the split's {len(frame_ids)} frames")
    return frame_ids[int(frame)]


def run(args: argparse.Namespace) -> int:
    from ..errors import I2PBenchError, PluginError
    from ..execution.devices import resolve_device
    from ..registry.build import default_registry
    from ..report import overlay
    from ..runs.environment import fix_threads
    from ..runs.jobs import prepare
    from ..scoring.pose import pose_errors
    from ..scoring.protocol import Protocol

    if args.out and Path(args.out).suffix.lower() != ".png":  # checked before any frame is loaded or run
        raise I2PBenchError(f"--out {args.out}: viz writes a PNG; give a path ending in .png")
    fix_threads()
    device = str(resolve_device(args.device))
    registry = default_registry()
    combinations = chosen_combinations(registry, args)
    if len(combinations) != 1:
        labels = "; ".join(c.label for c in combinations)
        raise PluginError(f"viz draws one combination, these options give {len(combinations)}: {labels}")
    dataset = open_dataset(registry, args)
    frame_id = resolve_frame(dataset.frame_ids(), args.frame)
    job = prepare(registry, combinations, args.weights, device, dataset.name)[0]
    frame = Protocol(seed=args.seed).apply(dataset.load(frame_id))
    outcome = job.pipeline.run(frame)
    out = args.out or f"viz/{dataset.name}-{dataset.split}-{frame_id.replace('/', '-')}.png"
    estimate = outcome.estimate
    summary = overlay.errors_text(estimate.T, frame.T_gt) if estimate.ok else f"failed: {estimate.message}"
    print(f"{job.label} on {dataset.name}/{dataset.split} {frame_id}: {summary}", file=sys.stderr)
    if estimate.ok and pose_errors(estimate.T, frame.T_gt).rre_deg > 180:
        print(f"i2pbench: note: {overlay.RRE_NOTE}", file=sys.stderr)
    _write(out, overlay.compose(_panels(frame, outcome, job.label, args)))
    print(f"written: {out}", file=sys.stderr)
    return 0


def _write(out: str, image: np.ndarray) -> None:
    """The PNG, or an error naming the path when it cannot be written (the pose errors are printed already)."""
    from ..errors import I2PBenchError
    from ..report import overlay

    try:
        overlay.write_png(out, image)
    except OSError as exc:
        raise I2PBenchError(f"--out {out}: could not write the PNG ({exc.strerror or exc})") from None


def _panels(frame, outcome, label: str, args: argparse.Namespace) -> list:
    """The three pose panels, then the edge and match panels asked for, from the run's trace (skipped when their
    stage did not finish)."""
    from ..report import overlay

    estimate = outcome.estimate
    panels = overlay.pose_panels(frame, estimate.T, failure=estimate.message, radius=args.radius)
    panels[0][0].insert(0, f"{frame.dataset} {frame.frame_id}: {label}")
    if args.edges and outcome.kp2d is not None and outcome.kp3d is not None:
        panels.append(overlay.edges_panel(frame, outcome.kp2d, outcome.kp3d))
    if args.matches and outcome.matches is not None:
        panels.append(overlay.matches_panel(frame, outcome.kp2d, outcome.kp3d, outcome.matches, estimate.inliers))
    return panels
