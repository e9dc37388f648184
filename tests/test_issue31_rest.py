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
