"""Splits by scene over all the real KITTI here: the committed split file, k-fold by scene, and the CLI using them."""

import itertools
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from test_train_cli import TINY

from i2pbench.boards.crossval import cross_validated, scene_bootstrap
from i2pbench.data.kitti_drives import (
    DEFAULT_SPLIT_FILE,
    KittiDrives,
    deal_folds,
    fold_splits,
    load_split_file,
    parse_fold,
)
from i2pbench.errors import DataError
from i2pbench.weights.checkpoints import load_checkpoint

FOLDERS = ("kitti_drives", "kitti_real", "kitti_odometry")


def side_of(splits: dict) -> dict[str, str]:
    """scene -> the one split holding it (asserting there is exactly one)."""
    out = {}
    for split, scenes in splits.items():
        for scene in scenes:
            assert scene not in out, f"{scene} is in {out.get(scene)} and {split}"
            out[scene] = split
    return out


def test_the_committed_file_keeps_every_scene_and_shared_place_on_one_side():
    split_file = load_split_file(DEFAULT_SPLIT_FILE)
    sides = side_of(split_file.splits)
    assert set(sides) == set(split_file.scenes)  # every scene placed once
    scene_of = {seq: scene for scene, seqs in split_file.scenes.items() for seq in seqs}
    # ../shared/data/README.md: 46 is kitti_odometry/00's drive; 49, 50 and kitti_odometry/01 are one courtyard
    assert scene_of["kitti_drives/46"] == scene_of["kitti_odometry/00"]
    assert scene_of["kitti_drives/49"] == scene_of["kitti_drives/50"] == scene_of["kitti_odometry/01"]
    assert len(split_file.scenes) == 24 and len(scene_of) == 27  # 23 + 2 + 2 sequences
    assert [len(split_file.splits[s]) for s in ("train", "val", "test")] == [13, 5, 6]


def test_the_file_lists_every_sequence_on_disk_and_no_frame_is_on_two_sides(shared_data):
    on_disk = {f"{f}/{p.name}" for f in FOLDERS for p in (shared_data / f / "sequences").iterdir() if p.is_dir()}
    listed = {seq for seqs in load_split_file(DEFAULT_SPLIT_FILE).scenes.values() for seq in seqs}
    assert listed == on_disk
    ids = {s: KittiDrives(s, {"root": str(shared_data)}).frame_ids() for s in ("train", "val", "test", "all")}
    assert [len(ids[s]) for s in ("train", "val", "test", "all")] == [57, 8, 11, 76]
    for a, b in itertools.combinations(("train", "val", "test"), 2):
        assert not {i.split("/")[0] for i in ids[a]} & {i.split("/")[0] for i in ids[b]}, (a, b)
    assert sorted(ids["train"] + ids["val"] + ids["test"]) == sorted(ids["all"])
    frame = KittiDrives("test", {"root": str(shared_data)}).load("33/000000")  # read in place
    assert frame.frame_id == "33/000000" and frame.image.shape == (375, 1242, 3)


def test_deal_folds_snakes_so_sizes_differ_by_at_most_one():
    assert deal_folds(list("abcdefg"), 3) == [["a", "f", "g"], ["b", "e"], ["c", "d"]]


@pytest.mark.parametrize("folds", [3, 5, 8, 24])
def test_folds_partition_the_scenes_and_test_each_scene_once(folds):
    split_file = load_split_file(DEFAULT_SPLIT_FILE)
    tested = []
    for k in range(1, folds + 1):
        splits = fold_splits(split_file, k, folds)
        assert set(side_of(splits)) == set(split_file.scenes)  # train, val, test: disjoint, covering every scene
        assert splits["val"] == fold_splits(split_file, k % folds + 1, folds)["test"]  # val = the next fold
        tested += splits["test"]
    assert sorted(tested) == sorted(split_file.scenes)  # each scene is a test scene in exactly one fold


def test_bad_split_files_and_folds_are_refused_naming_the_problem(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenes: {a: [x/1], b: [y/2]}\ntrain: [a]\nval: [a]\ntest: [b]\n")
    with pytest.raises(DataError, match="scene 'a' is in both train and val"):
        load_split_file(bad)
    bad.write_text("scenes: {a: [x/1], b: [y/1]}\ntrain: [a]\ntest: [b]\n")
    with pytest.raises(DataError, match="sequence name '1' appears twice"):
        load_split_file(bad)
    bad.write_text("scenes: {a: [x/1], b: [y/2]}\ntrain: [a]\n")
    with pytest.raises(DataError, match="scenes in no split: b"):
        load_split_file(bad)
    for text in ("2/2", "0/5", "6/5", "a/5", "3"):
        with pytest.raises(DataError, match="expected K/N"):
            parse_fold(text)
    with pytest.raises(DataError, match="only 24 scenes"):
        fold_splits(load_split_file(DEFAULT_SPLIT_FILE), 1, 25)


def test_scene_bootstrap_resamples_whole_scenes():
    values = np.array([1.0, 1.0, 1.0, 0.0])  # scene a: three frames registered; scene b: one frame missed
    est, low, high = scene_bootstrap(values, ["a", "a", "a", "b"], np.mean, draws=500)
    assert est == 0.75 and low == 0.0 and high == 1.0  # a draw of {b, b} gives 0, of {a, a} gives 1
    assert scene_bootstrap(values, ["a", "a", "a", "b"], np.mean, draws=500) == (est, low, high)  # seeded
    assert scene_bootstrap(np.ones(4), list("abcd"), np.mean, draws=50) == (1.0, 1.0, 1.0)
    frames = {"frame_id": ["1/0", "1/1", "2/0"], "rte_m": [0.1, 9.0, 0.1], "rre_deg": [0.1, 9.0, 0.1]}
    records = pd.DataFrame({"combination": "c", "weights": "w", **frames, "n_true_matches": [10, 0, 2]})
    row = cross_validated(records, lambda f: f.split("/")[0]).iloc[0]
    assert row["frames"] == 3 and row["scenes"] == 2
    assert row["Acc. with true matches (%) ↑"] == 33.33  # 1 of 3 frames: the third frame's success is chance


def cli(*args):
    return subprocess.run([sys.executable, "-m", "i2pbench.cli", *args], capture_output=True, text=True, timeout=600)


def test_run_with_a_fold_runs_its_test_scenes_into_the_folds_own_board(shared_data, tmp_path):
    done = cli("run", "--dataset", "kitti-drives", "--data-root", str(shared_data), "--split", "test", "--fold", "4/5",
               "--extractor", "random", "--extractor3d", "random", "--matcher", "oracle", "--solver", "epnp-ransac",
               "--runs-dir", str(tmp_path), "--quiet")  # fmt: skip
    assert done.returncode == 0, done.stderr
    expected = KittiDrives("test", {"root": str(shared_data), "fold": "4/5"}).frame_ids()
    frames = pd.concat(map(pd.read_parquet, (tmp_path / "kitti-drives-test-fold4of5" / "frames").glob("*.parquet")))
    assert sorted(frames["frame_id"]) == sorted(expected)
    assert (tmp_path / "leaderboards" / "kitti-drives-test-fold4of5-random-random-oracle-epnp-ransac.md").is_file()
    refused = cli("run", "--dataset", "kitti", "--data-root", str(shared_data / "kitti_real"), "--fold", "1/5",
                  "--matcher", "oracle", "--runs-dir", str(tmp_path), "--quiet")  # fmt: skip
    assert refused.returncode != 0 and "--fold: dataset 'kitti' has no fold config" in refused.stderr


def test_train_with_a_fold_trains_on_that_folds_scenes_and_records_the_fold(shared_data, tmp_path):
    out = tmp_path / "w.pt"
    done = cli("train", "--dataset", "kitti-drives", "--data-root", str(shared_data), "--fold", "2/5",
               "--out", str(out), "--steps", "1", "--validate-every", "1", "--val-frames", "1", "--cache-dir", "none",
               "--threads", "1", "--quiet", *TINY)  # fmt: skip
    assert done.returncode == 0, done.stderr
    meta = load_checkpoint(out).meta
    fold = {s: KittiDrives(s, {"root": str(shared_data), "fold": "2/5"}) for s in ("train", "val")}
    assert meta["trained_on"]["fold"] == "2/5" and meta["trained_on"]["frames"] == len(fold["train"].frame_ids())
    assert meta["trained_on"]["split_file"]["name"] == DEFAULT_SPLIT_FILE
    assert "kitti-drives[fold 2/5]/train" in done.stderr
