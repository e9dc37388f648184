"""Issue 31, the rest: a file name that is not UTF-8, unwritable folders, boards that do not overwrite each other,
labelled progress, and the weak list. Each: one clear error naming the file or option, or a failed frame naming
the file with the run going on; nothing already computed lost."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pandas as pd
from test_cli_errors import i2pbench
from test_data_bad_input import KITTI, needs_kitti

CLASSIC = ["--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]


def _kitti_frames(root: Path, n: int = 2) -> Path:
    """the first `n` real frames of sequence 00 under root/sequences/00."""
    seq = root / "sequences" / "00"
    for stem in [f"{i:06d}" for i in range(n)]:
        for rel in (f"velodyne/{stem}.bin", f"image_2/{stem}.png"):
            (seq / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(KITTI / rel, seq / rel)
    shutil.copyfile(KITTI / "calib.txt", seq / "calib.txt")
    return root


def _records(run: Path) -> pd.DataFrame:
    return pd.concat([pd.read_parquet(p) for p in sorted((run / "frames").glob("*.parquet"))], ignore_index=True)


# ---- fault 9: a frame file name that is not UTF-8 fails that frame, named; the run goes on ----


@needs_kitti
def test_a_frame_file_name_that_is_not_utf8_fails_that_frame_named_and_the_run_goes_on(tmp_path):
    root = _kitti_frames(tmp_path / "kitti", 3)
    seq = os.fsencode(root / "sequences" / "00")
    for folder, ext in ((b"velodyne", b".bin"), (b"image_2", b".png")):  # frame 000001 renamed to 00000\xff
        os.rename(seq + b"/" + folder + b"/000001" + ext, seq + b"/" + folder + b"/00000\xff" + ext)
    runs = tmp_path / "runs"
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), *CLASSIC, "--frames", "3"]
    done = i2pbench(*args, "--runs-dir", str(runs), "--quiet", cwd=tmp_path)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "| canny > depth > oracle > epnp-ransac | none | 3 | 1 |" in done.stdout  # 3 frames, 1 failure
    records = _records(runs / "kitti-all").set_index("frame_id").sort_index()
    assert list(records.index) == ["00/000000", "00/000002", "00/00000\\xff"]
    assert list(records["status"]) == ["ok", "ok", "failed"]
    bad = records.loc["00/00000\\xff"]
    assert bad["failed_component"] == "dataset 'kitti'"
    assert bad["error"] == (
        f"dataset 'kitti' frame '00/00000\\xff': the file name is not UTF-8 ({root}/sequences/00/velodyne/00000\\xff"
        f".bin, {root}/sequences/00/image_2/00000\\xff.png), which results cannot store; rename it"
    )
    again = i2pbench(*args, "--runs-dir", str(runs), "--quiet", cwd=tmp_path)  # every frame, the failed one too,
    assert again.returncode == 0 and again.stdout == done.stdout  # comes back from the cache as stored
