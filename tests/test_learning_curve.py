"""The learning curve's runs (scripts/learning_curve.py): nested drive subsets that keep val and test, and arms
that differ only in their starting weights."""

from argparse import Namespace

import learning_curve as curve  # scripts/ is on pytest's path, as on a script's

from i2pbench.data.kitti_drives import DEFAULT_SPLIT_FILE, load_split_file


def test_drive_subsets_are_nested_prefixes_of_the_train_list_with_the_files_val_and_test(tmp_path):
    committed = load_split_file(DEFAULT_SPLIT_FILE)
    train = committed.splits["train"]
    assert curve.split_file_for(13, tmp_path) == DEFAULT_SPLIT_FILE  # all drives: the committed file itself
    for drives in (1, 3, 10):
        subset = load_split_file(curve.split_file_for(drives, tmp_path))  # its checks: every scene on one side
        assert subset.splits["train"] == train[:drives]
        assert subset.splits["val"] == committed.splits["val"] and subset.splits["test"] == committed.splits["test"]
        assert {s: committed.scenes[s] for s in subset.scenes} == subset.scenes  # scenes kept whole
        assert set(subset.scenes) == set(train[:drives]) | set(committed.splits["val"]) | set(committed.splits["test"])
    assert load_split_file(curve.split_file_for(3, tmp_path)).scenes["2011_09_26_drive_0101"] == (
        "kitti_drives/46",
        "kitti_odometry/00",
    )  # a place two folders share trains on both of its sequences or on neither


def test_the_arms_differ_only_in_their_starting_weights_and_step_count(tmp_path):
    args = Namespace(work=tmp_path, steps=150, lr=1e-4, data_root="data")
    synthetic = curve.train_argv("synthetic-3", "synthetic", 3, args)
    scratch = curve.train_argv("scratch-3", "scratch", 3, args)
    assert synthetic[synthetic.index("--steps") + 1] == "8650" and scratch[scratch.index("--steps") + 1] == "150"
    assert (tmp_path / "runs" / "synthetic-3.pt").read_bytes() == curve.SHIPPED.read_bytes()  # a copy continues
    assert not (tmp_path / "runs" / "scratch-3.pt").exists()
    differ = {"--force", "8650", "150"} | {str(tmp_path / "runs" / f"{n}.pt") for n in ("synthetic-3", "scratch-3")}
    differ |= {str(tmp_path / "tb" / n) for n in ("synthetic-3", "scratch-3")}
    assert [a for a in synthetic if a not in differ] == [a for a in scratch if a not in differ]
