"""Issue 31, the rest: a file name that is not UTF-8, unwritable folders, boards that do not overwrite each other,
labelled progress, and the weak list. Each: one clear error naming the file or option, or a failed frame naming
the file with the run going on; nothing already computed lost."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pandas as pd
import pytest
from test_cli_errors import assert_refused, i2pbench
from test_data_bad_input import KITTI, RECORDS, needs_kitti, needs_nuscenes

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


def _board_rows(stdout: str) -> list[dict[str, str]]:
    """The printed board's rows as {column: cell}, whatever columns later versions add."""
    lines = [line for line in stdout.splitlines() if line.startswith("| ")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    return [dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True)) for line in lines[1:]]


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
    (row,) = _board_rows(done.stdout)
    assert (row["combination"], row["frames"], row["failures"]) == ("canny > depth > oracle > epnp-ransac", "3", "1")
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


# ---- fault 10: unwritable HOME, synthetic root, data synth --root, nuScenes dataroot, --out: one error line each ----
# The suite may run as root, which writes through any mode bits; a path under a regular file is unwritable for root
# too (NotADirectoryError / FileExistsError, the same OSError a read-only folder gives).


@pytest.fixture
def blocked(tmp_path) -> Path:
    """a regular file: nothing can be written under it."""
    path = tmp_path / "file"
    path.write_text("")
    return path


def test_an_unwritable_home_is_one_error_naming_the_cache_folder_and_xdg_cache_home(tmp_path, blocked):
    done = i2pbench("run", "--frames", "1", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path,
                    env={"HOME": str(blocked), "XDG_CACHE_HOME": ""})  # fmt: skip
    cache = blocked / ".cache" / "i2pbench"
    assert_refused(done, "dataset 'synthetic' (its default root)", f"{cache}/synthetic-v", "Not a directory",
                   f"in the i2pbench cache folder {cache}", "set XDG_CACHE_HOME to a writable folder")  # fmt: skip
    assert not (tmp_path / "runs").exists()


def test_an_unwritable_synthetic_root_is_one_error_naming_data_root(tmp_path, blocked):
    done = i2pbench("run", "--frames", "1", "--data-root", str(blocked / "syn"), cwd=tmp_path)
    assert_refused(done, f"dataset 'synthetic' --data-root {blocked / 'syn'}", f"{blocked / 'syn'}/sequences")


def test_data_synth_into_an_unwritable_root_is_one_error(tmp_path, blocked):
    done = i2pbench("data", "synth", "--root", str(blocked / "syn"), "--train", "1", "--val", "1", "--test", "1",
                    cwd=tmp_path)  # fmt: skip
    assert_refused(done, f"data synth --root {blocked / 'syn'}: could not write the frames", "Not a directory")


@needs_nuscenes
def test_a_nuscenes_dataroot_into_an_unwritable_folder_is_one_error(tmp_path, blocked):
    done = i2pbench("data", "nuscenes-dataroot", "--records", str(RECORDS), "--out", str(blocked / "nus"),
                    cwd=tmp_path)  # fmt: skip
    assert_refused(done, f"data nuscenes-dataroot --out {blocked / 'nus'}: could not write it", "Not a directory")


@needs_kitti
def test_an_unwritable_out_is_one_error_for_run_and_table_and_nothing_computed_is_lost(tmp_path, blocked):
    root = _kitti_frames(tmp_path / "kitti", 1)
    runs = tmp_path / "runs"
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), *CLASSIC, "--runs-dir", str(runs)]
    done = i2pbench(*args, "--out", str(blocked / "board"), cwd=tmp_path)
    assert_refused(done, f"could not write the leaderboard into {blocked}", "rerun with --out STEM")
    assert "| kitti | all | canny > depth > oracle > epnp-ransac |" in done.stdout  # printed before the error
    assert len(list((runs / "kitti-all" / "frames").glob("*.parquet"))) == 1  # the frame is kept
    board = tmp_path / "board"
    assert i2pbench(*args, "--out", str(board), "--quiet", cwd=tmp_path).returncode == 0
    table = i2pbench("table", "--preset", "classic-oracle", f"KITTI={board}.csv", "--out", str(blocked / "t"),
                     cwd=tmp_path)  # fmt: skip
    assert_refused(table, f"--out {blocked / 't'}: could not write the table", f"{blocked}: a file is there")
    assert "KITTI" in table.stdout  # the table itself was printed


def test_an_os_error_reaching_the_command_line_is_one_line_naming_the_path(monkeypatch, capsys, tmp_path):
    import errno

    from i2pbench import cli
    from i2pbench.commands import plugins

    def fails(args):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "x"))

    monkeypatch.setattr(plugins, "run", fails)
    assert cli.main(["plugins"]) == 2
    assert capsys.readouterr().err == f"i2pbench: error: {tmp_path / 'x'}: Permission denied\n"


# ---- first contact 2: a run's board never replaces another's ----


@pytest.mark.parametrize(
    ("options", "name"),
    [
        ([], "synthetic-test"),
        (["--preset", "default"], "synthetic-test"),
        (["--preset", "paper-table-1"], "synthetic-test-paper-table-1"),
        (["--preset", "baselines,edge-ablation"], "synthetic-test-baselines+edge-ablation"),
        (["--grid", "leaderboards/golden/classic.yaml"], "synthetic-test-classic"),
        (["--matcher", "oracle", "--solver", "epnp-ransac,poselib"], "synthetic-test-oracle-epnp-ransac+poselib"),
        (["--weights", "untrained"], "synthetic-test-weights-untrained"),
        (["--corruption", "fog:3"], "synthetic-test-fog_3"),
        (["--robustness", "--severities", "1,3"], "synthetic-test-robustness-s1+3"),
        (["--seed", "2"], "synthetic-test-seed2"),
    ],
)
def test_the_default_board_is_named_by_what_was_run(options, name):
    from i2pbench.cli import build_parser
    from i2pbench.commands.run import board_name

    assert board_name("synthetic-test", build_parser(("run",)).parse_args(["run", *options])) == name


def test_conf_overrides_name_their_board_by_a_hash_of_the_values():
    from i2pbench.cli import build_parser
    from i2pbench.commands.run import board_name

    def name(*conf: str) -> str:
        args = ["run", *[a for c in conf for a in ("--conf", c)]]
        return board_name("kitti-all", build_parser(("run",)).parse_args(args))

    assert name("solver.ransac_iters=10").startswith("kitti-all-conf-")
    assert name("solver.ransac_iters=10") != name("solver.ransac_iters=20")
    assert name("a.b=1", "c.d=2") == name("c.d=2", "a.b=1")  # the order they are given in does not matter
    many = build_parser(("run",)).parse_args(["run", "--extractor", ",".join(["canny"] * 60)])
    assert len(board_name("x", many)) <= 120  # a file name, not the whole grid


@needs_kitti
def test_a_grid_run_does_not_replace_the_board_of_a_run_of_other_stages(tmp_path):
    from i2pbench.runs import board_env  # a board in the default layout is still traced to its run's store

    root = _kitti_frames(tmp_path / "kitti", 1)
    grid = tmp_path / "mine.yaml"
    grid.write_text("base: {extractor2d: canny, extractor3d: depth, matcher: oracle}\ngrid: {solver: [poselib]}\n")
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), "--runs-dir", "runs"]
    first = i2pbench(*args, *CLASSIC, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    boards = tmp_path / "runs" / "leaderboards"
    classic = boards / "kitti-all-canny-depth-oracle-epnp-ransac.csv"
    assert f"written: {Path('runs/leaderboards/kitti-all-canny-depth-oracle-epnp-ransac.csv')}" in first.stderr
    before = classic.read_bytes()
    second = i2pbench(*args, "--grid", str(grid), cwd=tmp_path)
    assert second.returncode == 0, second.stderr
    assert f"written: {Path('runs/leaderboards/kitti-all-mine.csv')}" in second.stderr
    assert classic.read_bytes() == before  # the first board is still there, unchanged
    assert list(pd.read_csv(boards / "kitti-all-mine.csv")["combination"]) == ["canny > depth > oracle > poselib"]
    out = tmp_path / "chosen"  # --out STEM still writes where it is told
    assert i2pbench(*args, *CLASSIC, "--out", str(out), "--quiet", cwd=tmp_path).returncode == 0
    written = sorted(p.name for p in tmp_path.glob("chosen*"))
    assert written == ["chosen.csv", "chosen.env.json", "chosen.md", "chosen.parquet"]
    assert board_env._store_of(boards / "kitti-all-mine.csv") == tmp_path / "runs" / "kitti-all"


# ---- first contact 4: the progress bar names what runs; reuse of the cache is said ----


@needs_kitti
def test_the_progress_bar_names_the_grid_and_the_combination_and_cache_reuse_is_counted(tmp_path):
    root = _kitti_frames(tmp_path / "kitti", 2)
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), "--runs-dir", "runs"]
    args += ["--extractor", "canny,lsd", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]
    first = i2pbench(*args, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    bar = first.stderr.replace("\r", "\n")
    assert "2 combination(s) x 2 frames: 100%|" in bar and "4/4" in bar
    assert "canny > depth > oracle > epnp-ransac]" in bar and "lsd > depth > oracle > epnp-ransac]" in bar
    assert f"0 of 4 frames reused from the cache in {Path('runs/kitti-all')}\n" in first.stderr
    more = i2pbench(*[a if a != "canny,lsd" else "canny,lsd,random" for a in args], cwd=tmp_path)
    assert more.returncode == 0, more.stderr
    assert "3 combination(s) x 2 frames: 100%|" in more.stderr.replace("\r", "\n")
    assert f"4 of 6 frames reused from the cache in {Path('runs/kitti-all')}\n" in more.stderr
    assert "reused" not in i2pbench(*args, "--quiet", cwd=tmp_path).stderr  # --quiet: the board and errors only


# ---- weak list: why frames failed, latency from other thread counts, values that mean nothing ----


@needs_kitti
def test_failed_frames_are_counted_by_reason_on_the_terminal(tmp_path):
    root = _kitti_frames(tmp_path / "kitti", 3)
    seq = os.fsencode(root / "sequences" / "00")
    for stem, bad in ((b"000001", b"00000\xfe"), (b"000002", b"00000\xff")):  # two frames failing the same way
        for folder, ext in ((b"velodyne", b".bin"), (b"image_2", b".png")):
            os.rename(seq + b"/" + folder + b"/" + stem + ext, seq + b"/" + folder + b"/" + bad + ext)
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), *CLASSIC, "--runs-dir", "runs"]
    done = i2pbench(*args, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    at = lines.index("2 of 3 frames failed; by reason (count x combination: reason, e.g. a frame):")
    assert lines[at + 1] == (
        "  2 x canny > depth > oracle > epnp-ransac: dataset 'kitti' frame <id>: the file name is not UTF-8 (<file>, "
        "<file>), which results cannot store; rename it (e.g. 00/00000\\xfe)"
    )
    assert "frames failed" not in i2pbench(*args, "--quiet", cwd=tmp_path).stderr


@needs_kitti
def test_latency_reused_from_another_thread_count_is_said(tmp_path):
    root = _kitti_frames(tmp_path / "kitti", 2)
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), *CLASSIC, "--runs-dir", "runs"]
    assert "note: the latency" not in i2pbench(*args, "--threads", "1", cwd=tmp_path).stderr
    same = i2pbench(*args, "--threads", "1", cwd=tmp_path)
    assert "2 of 2 frames reused" in same.stderr and "note: the latency" not in same.stderr
    other = i2pbench(*args, "--threads", "2", cwd=tmp_path)
    assert other.returncode == 0, other.stderr
    assert (
        "note: the latency of 2 frame(s) reused from the cache was measured at 1 thread(s), not this run's 2; "
        "--overwrite measures them again"
    ) in other.stderr


def test_epochs_0_is_refused(tmp_path):
    done = i2pbench("train", "--out", str(tmp_path / "w.pt"), "--epochs", "0", cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.startswith("usage: i2pbench train")
    assert_refused(done, "--epochs", "'0' is not a finite positive number")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("split", ["--train", "--val", "--test"])
def test_data_synth_refuses_a_negative_frame_count(tmp_path, split):
    done = i2pbench("data", "synth", "--root", str(tmp_path / "syn"), split, "-1", cwd=tmp_path)
    assert_refused(done, split, "'-1' is not 0 or a positive integer")
    assert not (tmp_path / "syn").exists()


@pytest.mark.parametrize("text", ["", "# nothing yet\n", "base: {}\ngrid: {}\n"])
def test_an_empty_grid_file_is_refused_instead_of_running_the_default(tmp_path, text):
    grid = tmp_path / "empty.yaml"
    grid.write_text(text)
    done = i2pbench("run", "--grid", str(grid), "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, f"--grid {grid}: the file names no stage", "expected base: {kind: name}")
    assert not (tmp_path / "runs").exists()


def test_a_tolerance_given_twice_is_refused():
    from i2pbench.boards.regression_gate import parse_tolerances
    from i2pbench.errors import I2PBenchError

    assert [t.metric for t in parse_tolerances("acc=-2,rte=+0.05")] == ["acc", "rte"]
    with pytest.raises(I2PBenchError, match=r"tolerance 'acc=-2,rte=\+0.05,acc=-1': acc given twice; give each"):
        parse_tolerances("acc=-2,rte=+0.05,acc=-1")


# ---- weak list: an image whose size does not fit the calibration, or no camera's size ----


@needs_kitti
def test_an_image_of_another_size_than_the_calibration_fails_that_frame_naming_both_files(tmp_path):
    import cv2

    from i2pbench.data.kitti import read_frame

    root = _kitti_frames(tmp_path / "kitti", 2)
    seq = root / "sequences" / "00"
    image = cv2.imread(str(seq / "image_2" / "000001.png"))
    half = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2))
    cv2.imwrite(str(seq / "image_2" / "000001.png"), half)
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(root), *CLASSIC, "--runs-dir", "runs"]
    done = i2pbench(*args, "--quiet", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    records = _records(tmp_path / "runs" / "kitti-all").set_index("frame_id").sort_index()
    assert list(records["status"]) == ["ok", "failed"]
    K = read_frame(seq, "000000").K  # the full-size frame still fits
    assert records.loc["00/000001", "error"] == (
        f"{seq}/image_2/000001.png: the image is {half.shape[1]} x {half.shape[0]} px, but the intrinsics of "
        f"{seq}/calib.txt put the principal point at ({K[0, 2]:.1f}, {K[1, 2]:.1f}), outside its middle half: the "
        "image does not fit this calibration (resized or cropped?)"
    )


def test_an_image_past_16384_px_a_side_is_refused_before_decoding(tmp_path):
    import struct
    import zlib

    import cv2
    import numpy as np

    from i2pbench.data.images import PNG_END, PNG_START, header_size, read_image
    from i2pbench.errors import DataError

    ihdr = struct.pack(">II5B", 40000, 40000, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    huge = tmp_path / "huge.png"
    huge.write_bytes(PNG_START + chunk + PNG_END)  # the header of a 40000 x 40000 image (4.8 GB decoded)
    with pytest.raises(DataError, match=rf"{huge}: the image is 40000 x 40000 px, past 16384 px a side"):
        read_image(huge)
    small = np.zeros((30, 50, 3), np.uint8)
    for ext in (".png", ".jpg"):  # the header is read right, so real images pass
        data = cv2.imencode(ext, small)[1].tobytes()
        assert header_size(data) == (50, 30)


# ---- weak list: a --conf or --data-conf value of another kind than its default ----


@pytest.mark.parametrize(
    ("conf", "named"),
    [
        ("solver.reprojection_error_px=six", "config reprojection_error_px = 'six' is a string, but "
         "reprojection_error_px takes a number (default 6.5)"),
        ("solver.iterations=[5000]", "config iterations = [5000] is a list, but iterations takes a number"),
        ("solver.seed=true", "config seed = True is true or false, but seed takes a number"),
    ],
)  # fmt: skip
def test_a_conf_value_of_another_kind_than_its_default_is_refused_naming_the_key(tmp_path, conf, named):
    done = i2pbench("run", *CLASSIC, "--conf", conf, "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, "solver 'epnp-ransac'", named)
    assert not (tmp_path / "runs").exists()


def test_a_cameras_string_is_refused_not_read_as_a_list_of_characters():
    from i2pbench.data.nuscenes import NuScenes
    from i2pbench.stages.config import ConfigError

    with pytest.raises(ConfigError, match=r"config cameras = 'CAM_FRONT' is a string, but cameras takes a list"):
        NuScenes("val", {"root": "/nowhere", "cameras": "CAM_FRONT"})
    assert NuScenes("val", {"cameras": ["CAM_BACK"], "root": None}).conf["cameras"] == ["CAM_BACK"]


def test_numbers_stand_for_each_other_and_none_goes_anywhere():
    from i2pbench.stages.config import merge_conf

    merged = merge_conf({"radius": 3.0, "count": 2, "name": "x", "auto": None}, {"radius": 4, "count": 2.5,
                        "name": None, "auto": [1]}, "test")  # fmt: skip
    assert merged == {"radius": 4, "count": 2.5, "name": None, "auto": [1]}


@pytest.mark.parametrize("value", ["0", "-3", ".inf"])
def test_a_radius_or_reprojection_bound_that_is_not_positive_is_refused(tmp_path, value):
    conf = f"solver.reprojection_error_px={value}"
    done = i2pbench("run", *CLASSIC, "--conf", conf, "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, "solver 'epnp-ransac': config reprojection_error_px =", "a finite positive number")
    assert not (tmp_path / "runs").exists()


def test_nan_is_refused_for_any_number_and_positive_lengths_pass():
    from i2pbench.stages.config import ConfigError, merge_conf

    defaults = {"confidence": 0.99, "pair_radius_px": 16.0, "offset": 1.0}
    with pytest.raises(ConfigError, match="test: config confidence = nan is no number to compare with"):
        merge_conf(defaults, {"confidence": float("nan")}, "test")
    with pytest.raises(ConfigError, match="config pair_radius_px = -1: a radius or error bound is a finite positive"):
        merge_conf(defaults, {"pair_radius_px": -1}, "test")
    assert merge_conf(defaults, {"pair_radius_px": 2.5, "offset": -4.0}, "test")["offset"] == -4.0  # not a length
    assert merge_conf({"ego_radius_m": 1.2}, {"ego_radius_m": 0}, "test") == {"ego_radius_m": 0}  # 0: keep all


# --- checkpoint messages (issue 31, weak list): never advise unpickling, name the folder, never an empty reason


def test_a_checkpoint_of_python_objects_is_refused_without_advising_to_unpickle_it(tmp_path):
    import argparse

    import torch

    from i2pbench.errors import WeightsError
    from i2pbench.weights.checkpoints import load_checkpoint

    torch.save({"meta": "{}", "state": argparse.Namespace(a=1)}, tmp_path / "objects.pt")
    with pytest.raises(WeightsError) as caught:
        load_checkpoint(tmp_path / "objects.pt")
    message = str(caught.value)
    assert message == (
        f"checkpoint {tmp_path / 'objects.pt'} is not a readable i2pbench checkpoint: it holds Python objects, "
        "not only tensors (not a file i2pbench wrote), and is not unpickled"
    )
    assert "weights_only" not in message


@pytest.mark.parametrize(
    "name, reason",
    [
        ("empty.pt", "is empty (0 bytes), not an i2pbench checkpoint"),
        ("no-meta.pt", "is not a readable i2pbench checkpoint: no 'meta' entry (a torch file, but not an i2pbench"),
        ("gone/x.pt", ": its folder {folder} does not exist"),
        ("folder", "is a folder, not a checkpoint file"),
    ],
)
def test_a_checkpoint_that_cannot_be_read_says_why(tmp_path, name, reason):
    import torch

    from i2pbench.errors import WeightsError
    from i2pbench.weights.checkpoints import load_checkpoint

    (tmp_path / "empty.pt").write_bytes(b"")
    torch.save({"state": {}}, tmp_path / "no-meta.pt")
    (tmp_path / "folder").mkdir()
    with pytest.raises(WeightsError) as caught:
        load_checkpoint(tmp_path / name)
    assert f"checkpoint {tmp_path / name}" in str(caught.value)
    assert reason.format(folder=tmp_path / "gone") in str(caught.value)
