"""Issue 31's weak list: `run --out` is a file stem, so what is not one (a device, a pipe, a folder) is refused before
any work and `board.csv` is read as the stem `board`; `--weights PATH` on a run with no learned stage is refused
instead of ignored; and `--weights auto` leaving a learned pipeline untrained because its extractor differs from the
shipped checkpoint's says so, naming the checkpoint and the extractor."""

from __future__ import annotations

import os
from pathlib import Path

from conftest import require
from test_cli_errors import assert_refused, i2pbench
from test_issue31_faults import SHIPPED
from test_report_html import KITTI

CLASSIC = ["--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]


def _run(tmp_path: Path, *args: str):
    require(KITTI)
    data = ["--dataset", "kitti", "--split", "all", "--data-root", str(KITTI), "--frames", "1"]
    return i2pbench("run", *data, "--runs-dir", str(tmp_path / "runs"), "--quiet", *args, cwd=tmp_path)


def _computed(tmp_path: Path) -> list[Path]:
    return list((tmp_path / "runs").rglob("*.parquet"))


def test_out_naming_a_device_is_refused_before_any_work(tmp_path):
    done = _run(tmp_path, *CLASSIC, "--out", os.devnull)
    assert_refused(done, f"--out {os.devnull} is not a regular file", "--out is a file stem (it writes STEM.csv")
    assert not Path(f"{os.devnull}.csv").exists() and _computed(tmp_path) == []


def test_out_naming_a_pipe_or_a_folder_is_refused(tmp_path):
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    assert_refused(_run(tmp_path, *CLASSIC, "--out", str(pipe)), f"--out {pipe} is not a regular file")
    assert_refused(_run(tmp_path, *CLASSIC, "--out", str(tmp_path)), f"--out {tmp_path} is a folder", "/board")
    assert _computed(tmp_path) == []


def test_out_ending_in_a_written_suffix_is_taken_as_the_stem_and_said(tmp_path):
    done = _run(tmp_path, *CLASSIC, "--out", str(tmp_path / "board.csv"))
    assert done.returncode == 0, done.stderr
    stem = tmp_path / "board"
    said = f"i2pbench: note: --out {stem}.csv is taken as the stem {stem}: writing {stem}.csv, {stem}.md, "
    assert said in done.stderr
    assert sorted(p.name for p in tmp_path.glob("board*")) == [
        "board.csv",
        "board.env.json",
        "board.md",
        "board.parquet",
    ]


def test_weights_for_a_run_without_a_learned_stage_is_refused_not_ignored(tmp_path):
    done = _run(tmp_path, *CLASSIC, "--weights", str(SHIPPED))
    assert_refused(
        done, f"--weights {SHIPPED}: no combination of this run has a learned stage", "canny > depth > oracle"
    )
    assert _computed(tmp_path) == []


def test_weights_untrained_or_auto_on_a_classic_run_is_fine(tmp_path):
    assert _run(tmp_path, *CLASSIC, "--weights", "untrained").returncode == 0


def test_auto_leaving_the_default_pipeline_untrained_for_another_extractor_says_why(tmp_path):
    done = _run(tmp_path, "--extractor", "canny")
    assert done.returncode == 0, done.stderr
    note = next(line for line in done.stderr.splitlines() if line.startswith("i2pbench: note: --weights auto"))
    assert note.startswith("i2pbench: note: --weights auto: canny > ")
    assert f"runs untrained: the shipped {SHIPPED.name} fits its learned stages but was trained with " in note
    assert "extractor2d 'lsd' (this row: 'canny')" in note and note.endswith(f"--weights {SHIPPED} uses them anyway")
    board = next(line for line in done.stdout.splitlines() if "| canny > " in line)
    assert "| untrained" in board  # what the note explains


def test_evaluate_out_is_checked_as_runs_is(tmp_path):
    assert _run(tmp_path, *CLASSIC).returncode == 0
    run = tmp_path / "runs" / "kitti-all"
    assert_refused(i2pbench("evaluate", str(run), "--out", os.devnull, cwd=tmp_path), f"--out {os.devnull} is not")
    done = i2pbench("evaluate", str(run), "--out", str(tmp_path / "again.md"), cwd=tmp_path)
    assert done.returncode == 0 and f"--out {tmp_path / 'again.md'} is taken as the stem" in done.stderr
    assert (tmp_path / "again.csv").is_file() and not (tmp_path / "again.md.csv").exists()
