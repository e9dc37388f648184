"""Issue 31's weak list: a YAML alias bomb in `--conf` (and any YAML a user hands us) is refused as one error naming
the option or file; `diagnose` and `domain-gap` report a frame that cannot be loaded, naming it, and go on."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from test_cli_errors import assert_refused, i2pbench
from test_data_bad_input import KITTI, needs_kitti

from i2pbench.data.kitti_drives import load_split_file
from i2pbench.data.yaml_input import AliasRefused, load
from i2pbench.errors import DataError

# nine levels of nine aliases: 9**9 (387 million) leaves from 200 bytes once anything walks it
BOMB = "{" + ", ".join([f"l0: &l0 [{', '.join(['x'] * 9)}]"] + [
    f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 9)
]) + "}"  # fmt: skip


def test_an_alias_is_refused_where_it_appears_and_plain_yaml_still_reads():
    with pytest.raises(AliasRefused, match=r"alias \*l0 refused"):
        load(BOMB)
    assert load("{a: [1, 2.5], b: null, c: 'x'}") == {"a": [1, 2.5], "b": None, "c": "x"}
    assert load("a: &anchor 1") == {"a": 1}  # an anchor alone repeats nothing


@pytest.mark.parametrize("option", ["--conf", "--data-conf"])
def test_an_alias_bomb_in_a_setting_is_one_error_naming_the_option(option, tmp_path):
    key = "matcher.filter_threshold" if option == "--conf" else "frames.test"
    done = i2pbench("run", option, f"{key}={BOMB}", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, f"argument {option}", "the value is not valid YAML (alias *l0 refused")
    assert not (tmp_path / "runs").exists()


def test_an_alias_in_a_grid_file_is_one_error_naming_the_file(tmp_path):
    grid = tmp_path / "grid.yaml"
    grid.write_text("base: &b {extractor2d: lsd}\ngrid: {extractor2d: [canny]}\nconfs: {matcher: *b}\n")
    done = i2pbench("run", "--grid", str(grid), "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, f"--grid {grid}: not valid YAML (alias *b refused", "line 3, column 18")


def test_an_alias_in_a_split_file_is_an_error_naming_the_file(tmp_path):
    split = tmp_path / "split.yaml"
    split.write_text("scenes: {a: &s [x/00]}\ntrain: [a]\nval: *s\ntest: []\n")
    with pytest.raises(DataError, match=rf"{split}: not valid YAML .*alias \*s refused"):
        load_split_file(split)


# ---- diagnose and domain-gap go on past a frame that cannot be loaded ----


def _kitti_copy(root: Path, broken: tuple[str, ...] = ()) -> Path:
    """sequence 00's first three frames, with the images of `broken` stems cut short."""
    seq = root / "sequences" / "00"
    for stem in ("000000", "000001", "000002"):
        for rel in (f"velodyne/{stem}.bin", f"image_2/{stem}.png"):
            (seq / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(KITTI / rel, seq / rel)
        if stem in broken:
            image = seq / "image_2" / f"{stem}.png"
            image.write_bytes(image.read_bytes()[:-1000])
    shutil.copyfile(KITTI / "calib.txt", seq / "calib.txt")
    return root


def _data(root: Path) -> list[str]:
    return ["--dataset", "kitti", "--split", "all", "--data-root", str(root), "--frames", "3"]


@needs_kitti
def test_diagnose_names_a_frame_it_cannot_load_and_summarises_the_others(tmp_path):
    root = _kitti_copy(tmp_path / "kitti", broken=("000001",))
    out = tmp_path / "diag.csv"
    done = i2pbench("diagnose", *_data(root), "--extractor3d", "depth", "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    image = root / "sequences" / "00" / "image_2" / "000001.png"
    assert f"i2pbench: warning: diagnose: frame 00/000001 skipped: {image}: truncated PNG" in done.stderr
    assert "i2pbench: note: diagnose: 1 of 3 frames skipped (named above)" in done.stderr
    assert pd.read_csv(out)["frames"].tolist() == [2]


@needs_kitti
def test_domain_gap_names_a_frame_it_cannot_load_and_compares_the_others(tmp_path):
    broken, whole = _kitti_copy(tmp_path / "broken", broken=("000002",)), _kitti_copy(tmp_path / "whole")
    out = tmp_path / "gap.csv"
    against = ["--against", "kitti", "--against-split", "all", "--against-root", str(whole)]
    done = i2pbench("domain-gap", *_data(broken), *against, "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "i2pbench: warning: domain-gap: frame 00/000002 skipped: " in done.stderr
    assert "i2pbench: note: domain-gap: 1 of 3 frames skipped (named above)" in done.stderr
    frames = pd.read_csv(out).set_index("statistic").loc["frames"]
    assert frames["kitti/all (broken) mean"] == 2 and frames["kitti/all (whole) mean"] == 3


@needs_kitti
def test_when_no_frame_loads_diagnose_is_one_error(tmp_path):
    root = _kitti_copy(tmp_path / "kitti", broken=("000000", "000001", "000002"))
    done = i2pbench("diagnose", *_data(root), "--extractor3d", "depth", cwd=tmp_path)
    assert_refused(done, "diagnose: none of the 3 frames of 'kitti' could be loaded (named above)")
    assert done.stderr.count("i2pbench: warning: diagnose: frame 00/00000") == 3
