"""Issue 31's faults: bad input, misuse and broken files get one clear error naming the file or option, and nothing
already made (real data, shipped weights, finished frames) is overwritten or lost."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import toy_plugin
from conftest import require
from test_cli_errors import ROOT, assert_refused, i2pbench
from test_data_bad_input import KITTI, RECORDS, needs_kitti, needs_nuscenes

from i2pbench.data.kitti import read_frame
from i2pbench.data.nuscenes import NuScenes
from i2pbench.data.nuscenes_dataroot import build_dataroot
from i2pbench.data.synthetic.dataset import SyntheticStreets
from i2pbench.errors import DataError, I2PBenchError, WeightsError
from i2pbench.weights.checkpoints import check_out


def _tree(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_size for p in sorted(root.rglob("*"))}


def _kitti_copy(tmp_path: Path) -> Path:
    root = tmp_path / "kitti"
    seq = root / "sequences" / "26"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "image_2").mkdir()
    (seq / "calib.txt").write_text("P2: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    (seq / "velodyne" / "000000.bin").write_bytes(b"\0" * 64)
    return root


def test_synthetic_refuses_to_generate_into_a_kitti_copy(tmp_path):
    root = _kitti_copy(tmp_path)
    before = _tree(root)
    with pytest.raises(DataError, match=r"kitti holds data not made by the synthetic generator \(it looks like KITTI"):
        SyntheticStreets("test", {"root": str(root), "frames": {"test": 1}}).frame_ids()
    assert _tree(root) == before  # not even an empty sequences/02


def test_synthetic_refuses_to_generate_into_a_nuscenes_dataroot(tmp_path):
    root = tmp_path / "nuscenes"
    (root / "v1.0-mini").mkdir(parents=True)
    (root / "samples" / "CAM_FRONT").mkdir(parents=True)
    before = _tree(root)
    with pytest.raises(DataError, match=r"nuscenes holds data not made .*looks like a nuScenes dataroot.*samples"):
        SyntheticStreets("val", {"root": str(root), "frames": {"val": 1}}).frame_ids()
    assert _tree(root) == before


def test_run_with_a_kitti_data_root_and_no_dataset_is_one_error_and_writes_nothing(tmp_path):
    root = _kitti_copy(tmp_path)
    before = _tree(root)
    done = i2pbench(
        "run", "--data-root", str(root), "--frames", "1", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path
    )
    assert_refused(done, str(root), "KITTI", "--dataset kitti")
    assert _tree(root) == before


def test_a_synthetic_root_the_generator_made_is_still_extended(tmp_path):
    """Another split generated into a root holding only the generator's own sequences is allowed."""
    root = tmp_path / "synthetic"
    conf = {"root": str(root), "frames": {"val": 1, "test": 1}, "workers": 1}
    SyntheticStreets("val", conf).frame_ids()
    assert SyntheticStreets("test", conf).frame_ids() == ["02/000000"]
    assert sorted(p.name for p in (root / "sequences").iterdir()) == ["01", "02"]


SHIPPED = ROOT / "plugins" / "edgeregnet" / "i2pbench_edgeregnet" / "weights" / "edgeregnet-cpu-synthetic.pt"


def test_train_refuses_to_write_into_the_installed_package(tmp_path):
    before = SHIPPED.read_bytes()
    siblings = sorted(p.name for p in SHIPPED.parent.iterdir())
    done = i2pbench("train", "--out", str(SHIPPED), "--steps", "1", "--force", cwd=tmp_path)
    assert_refused(done, f"--out {SHIPPED}", "inside the installed package")
    assert SHIPPED.read_bytes() == before
    assert sorted(p.name for p in SHIPPED.parent.iterdir()) == siblings  # no .resume, .log.jsonl or probe left


def test_train_never_overwrites_a_checkpoint_without_force(tmp_path):
    copy = tmp_path / "mine.pt"
    shutil.copyfile(SHIPPED, copy)
    done = i2pbench("train", "--out", str(copy), "--steps", "1", cwd=tmp_path)
    assert_refused(done, f"--out {copy}", "existing checkpoint", "--force")
    assert copy.read_bytes() == SHIPPED.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.pt"]


def test_train_resumes_its_own_checkpoint_and_continues_a_copy_only_with_force(tmp_path):
    copy = tmp_path / "mine.pt"
    shutil.copyfile(SHIPPED, copy)
    check_out(copy, force=True)  # a copy to fine-tune, said explicitly
    copy.with_name("mine.pt.resume").write_bytes(b"")  # a training of ours in progress: resumed without --force
    check_out(copy, force=False)
    check_out(tmp_path / "new.pt", force=False)
    with pytest.raises(WeightsError, match="is a folder"):
        check_out(tmp_path, force=True)


@pytest.mark.parametrize("lr", ["inf", "nan", "-1", "0", "1e-4x"])
def test_train_refuses_a_learning_rate_that_is_not_finite_and_positive(lr, tmp_path):
    done = i2pbench("train", "--out", str(tmp_path / "w.pt"), "--lr", lr, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.startswith("usage: i2pbench train")
    assert_refused(done, "--lr", repr(lr), "finite positive")
    assert list(tmp_path.iterdir()) == []


def test_training_stops_on_exploding_weights_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    from test_weights_and_training import LEARNED, Clean

    from i2pbench.registry.build import build_registry
    from i2pbench.stages.pipeline import Combination, Pipeline
    from i2pbench.training.config import TrainConfig
    from i2pbench.training.loop import Trainer
    from i2pbench.weights.checkpoints import load_checkpoint

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))

    def trainer(lr: float, steps: int) -> Trainer:
        pipeline = Pipeline.build(registry, Combination(LEARNED))
        config = TrainConfig(steps=steps, lr=lr, checkpoint_every=2, validate_every=1000, seed=1)
        return Trainer(pipeline, Clean("test"), None, tmp_path / "w.pt", config)

    trainer(0.05, 2).run({})
    good = (tmp_path / "w.pt").read_bytes()
    wild = trainer(1e30, 50)
    wild.resume()
    with pytest.raises(
        I2PBenchError, match=rf"training stopped at step \d+: the .* \(lr 1e\+30\); {tmp_path}/w.pt keeps"
    ):
        wild.run({})
    assert 2 < wild.step < 50
    assert (tmp_path / "w.pt").read_bytes() == good and load_checkpoint(tmp_path / "w.pt").meta["steps"] == 2
    with pytest.raises(I2PBenchError, match="training lr inf: give a finite positive number"):
        trainer(float("inf"), 2)


# ---- KITTI calib.txt: a key given twice; lines that are no calibration key ----


@pytest.fixture
def kitti_seq(tmp_path) -> Path:
    """a one-frame copy of real sequence 00, to break."""
    dst = tmp_path / "sequences" / "00"
    for rel in ("calib.txt", "velodyne/000000.bin", "image_2/000000.png"):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(KITTI / rel, dst / rel)
    return dst


@needs_kitti
def test_a_second_tr_line_is_an_error_naming_file_and_key(kitti_seq):
    seq = kitti_seq
    calib = seq / "calib.txt"
    text = calib.read_text()
    tr = next(line for line in text.splitlines() if line.startswith("Tr:"))
    calib.write_text(text + tr.replace(tr.split()[1], "0.5", 1) + "\n")
    lineno = len(text.splitlines()) + 1
    with pytest.raises(DataError, match=rf"{calib}:{lineno}: a second Tr line \(the first is line \d\); keep one"):
        read_frame(seq, "000000")


@needs_kitti
def test_calib_time_and_comment_lines_are_skipped(kitti_seq):
    seq = kitti_seq
    calib = seq / "calib.txt"
    plain = read_frame(seq, "000000")
    calib.write_text("# calibrated: 2011-09-26\ncalib_time: 09-Jan-2012 13:57:47\n\n" + calib.read_text())
    np.testing.assert_array_equal(read_frame(seq, "000000").K, plain.K)
    np.testing.assert_array_equal(read_frame(seq, "000000").T_cam_lidar, plain.T_cam_lidar)


# ---- nuScenes tables: a token given twice ----


@needs_nuscenes
@pytest.mark.parametrize("table", ["calibrated_sensor", "sample_data"])
def test_a_nuscenes_token_given_twice_is_an_error_naming_table_and_token(tmp_path, table):
    root = tmp_path / "nuscenes"
    build_dataroot([RECORDS], root)
    path = root / "v1.0-trainval" / f"{table}.json"
    rows = json.loads(path.read_text())
    path.write_text(json.dumps([*rows, {**rows[0], "filename": "elsewhere.jpg"}]))  # a second record, same token
    with pytest.raises(DataError, match=rf"{path}: token {rows[0]['token']} is given to two records"):
        NuScenes("val", {"root": str(root)}).frame_ids()


# ---- local workers are capped at the cores ----


def test_local_workers_are_capped_at_the_usable_cores_and_it_is_said(monkeypatch, capsys):
    from i2pbench.runs import executors

    monkeypatch.setattr(executors.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert executors.make_executor("local", 1000, threads=1).workers == 4
    assert capsys.readouterr().err == "i2pbench: note: --workers 1000 capped at 4, the cores this process may use\n"
    assert executors.make_executor("local", 3, threads=2).workers == 3
    assert capsys.readouterr().err == ""  # within the cores: nothing to say
    monkeypatch.setattr(executors.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert executors.make_executor("local", 8) is None  # one core: one worker, serial in this process


# ---- a runs folder with broken or foreign files: evaluate, report and run name the file ----

KITTI_ROOT = KITTI.parents[1]
CLASSIC = ["--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]


def _run(runs: Path, frames: int = 2, cwd: Path | None = None):
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI_ROOT), *CLASSIC]
    return i2pbench(*args, "--frames", str(frames), "--runs-dir", str(runs), "--quiet", cwd=cwd or runs.parent)


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> Path:
    """a runs folder of two invocations (2 frames, then 3), copied by each test before it breaks it."""
    require(KITTI)
    runs = tmp_path_factory.mktemp("stored") / "runs"
    assert _run(runs, 2).returncode == 0 and _run(runs, 3).returncode == 0
    return runs / "kitti-all"


def _copy(stored: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(stored, tmp_path / "kitti-all"))


def test_a_stored_pose_of_3_values_is_named_by_file_and_frame_and_the_rest_evaluates(stored, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    run = _copy(stored, tmp_path)
    path = sorted((run / "frames").glob("*.parquet"))[0]
    record = pq.read_table(path).to_pylist()[0]
    pq.write_table(pa.Table.from_pylist([{**record, "T_pred": [1.0, 2.0, 3.0]}]), path)
    done = i2pbench("evaluate", str(run), cwd=tmp_path)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert f"malformed result {path}" in done.stderr
    assert f"frame {record['frame_id']}'s T_pred holds 3 values, not the 16 of a 4 x 4 pose" in done.stderr
    assert "2 per-frame records of the grid's 3" in done.stderr  # the other frames still count


def test_a_truncated_invocation_record_is_named_and_the_others_still_report(stored, tmp_path):
    run = _copy(stored, tmp_path)
    first, last = sorted((run / "invocations").glob("*.json"))
    text = first.read_text()
    first.write_text(text[: text.index('"started"') + 5])  # cut inside a string, whatever the id's length
    for args in (["evaluate", str(run)], ["report", str(run), "--out", str(tmp_path / "r.html")]):
        done = i2pbench(*args, cwd=tmp_path)
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
        assert f"i2pbench: warning: {first}: not a readable invocation record (Unterminated string" in done.stderr
    assert "3 per-frame records of the grid's 3" in i2pbench("evaluate", str(run), cwd=tmp_path).stderr
    last.write_text("[1, 2]")
    done = i2pbench("evaluate", str(run), cwd=tmp_path)
    assert_refused(done, str(run), "no readable invocations/ files", "--invocation all")
    assert f"{last}: not a readable invocation record (a JSON list, not an object)" in done.stderr


def test_an_invocation_record_of_another_version_names_the_file_and_that_version(stored, tmp_path):
    run = _copy(stored, tmp_path)
    last = sorted((run / "invocations").glob("*.json"))[-1]
    meta = json.loads(last.read_text())
    meta["protocol"]["new_knob"] = 1
    meta["environment"]["packages"]["i2pbench"] = "9.0.0"
    last.write_text(json.dumps(meta))
    for args in (["evaluate", str(run)], ["report", str(run), "--out", str(tmp_path / "r.html")]):
        done = i2pbench(*args, cwd=tmp_path)
        assert_refused(done, str(last), "written by i2pbench 9.0.0 (commit", "new_knob")
    del meta["frames"]
    meta["protocol"].pop("new_knob")
    last.write_text(json.dumps(meta))
    assert_refused(i2pbench("evaluate", str(run), cwd=tmp_path), str(last), "KeyError: 'frames'")


def test_an_invocations_path_that_is_a_file_is_one_error_and_the_frames_stay(stored, tmp_path):
    runs = tmp_path / "runs"
    run = _copy(stored, runs)
    shutil.rmtree(run / "invocations")
    (run / "invocations").write_text("")
    frames = sorted(p.name for p in (run / "frames").iterdir())
    assert_refused(_run(runs, 2, cwd=tmp_path), f"{run / 'invocations'} is a file", "move it aside")
    assert sorted(p.name for p in (run / "frames").iterdir()) == frames


# ---- a checkpoint whose metadata is malformed ----


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda meta: meta.update(stages=["encoder2d"]), "meta field 'stages' is list"),
        (lambda meta: meta.pop("stages"), "meta field 'stages' is NoneType"),
        (lambda meta: meta["stages"].update(matcher={"name": 3}), "meta field 'stages.matcher' is not an object"),
        (lambda meta: meta.update(trained_on="synthetic"), "meta field 'trained_on' is str, not an object"),
        (lambda meta: meta.update(lineage=[1]), "meta field 'lineage' holds an entry that is not an object"),
    ],
    ids=["stages-list", "stages-missing", "stage-name", "trained-on-string", "lineage-entry"],
)
def test_a_checkpoint_with_malformed_meta_is_refused_naming_the_field(edit, named, tmp_path):
    import torch

    from i2pbench.weights.checkpoints import content_digest, load_checkpoint

    payload = torch.load(SHIPPED, map_location="cpu", weights_only=True)
    meta = json.loads(payload["meta"])
    edit(meta)
    payload["meta"] = json.dumps(meta)
    payload["sha256"] = content_digest(payload["meta"], payload["state"])  # well formed but for the meta
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    with pytest.raises(WeightsError, match=rf"checkpoint {bad} is malformed: {re.escape(named)}.*; refusing it"):
        load_checkpoint(bad)


# ---- table, compare and viz: what they take is said before any work ----


def test_table_and_compare_say_they_take_a_leaderboard_csv_or_parquet(stored, tmp_path):
    board = stored.parent / "leaderboards" / "kitti-all-canny-depth-oracle-epnp-ransac"
    for args in (
        ["table", "--preset", "classic-oracle", f"KITTI={board}.md"],
        ["compare", f"{board}.md", f"{board}.csv"],
    ):
        assert_refused(i2pbench(*args, cwd=tmp_path), f"{board}.md: a .md file", "leaderboard's .csv or .parquet")
    record = next((stored / "invocations").glob("*.json"))
    assert_refused(i2pbench("compare", f"{board}.csv", str(record), cwd=tmp_path), "baseline", "a .json file")
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    done = i2pbench("table", "--preset", "classic-oracle", f"KITTI={other}", cwd=tmp_path)
    assert_refused(done, f"leaderboard of KITTI {other}: not a leaderboard (no column combination)")


def test_viz_refuses_an_out_without_png_before_any_work(tmp_path):
    done = i2pbench("viz", "0", "--out", str(tmp_path / "picture"), cwd=tmp_path)
    assert_refused(done, f"--out {tmp_path / 'picture'}", "give a path ending in .png")
    assert list(tmp_path.iterdir()) == []  # no synthetic frames generated, nothing written


# ---- first contact: --version; --quiet is quiet ----


def test_version_prints_the_package_version(tmp_path):
    from i2pbench import __version__

    done = i2pbench("--version", cwd=tmp_path)
    assert done.returncode == 0 and done.stdout == f"i2pbench {__version__}\n"


def test_quiet_silences_the_written_lines_of_run_and_report(stored, tmp_path):
    runs = tmp_path / "runs"
    _copy(stored, runs)
    run = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI_ROOT), *CLASSIC, "--frames", "2"]
    run += ["--runs-dir", str(runs), "--out", str(tmp_path / "q")]
    loud, quiet = i2pbench(*run, cwd=tmp_path), i2pbench(*run, "--quiet", cwd=tmp_path)
    assert loud.returncode == quiet.returncode == 0
    assert f"written: {tmp_path / 'q.csv'}" in loud.stderr
    assert "written: " not in quiet.stderr and (tmp_path / "q.csv").is_file()
    assert "| kitti | all | canny > depth > oracle > epnp-ransac |" in quiet.stdout  # the board itself still shows
    report = ["report", str(runs / "kitti-all"), "--out", str(tmp_path / "r.html")]
    assert "written: " in i2pbench(*report, "--overlays", "0", cwd=tmp_path).stderr  # the line, not the pictures
    quiet = i2pbench(*report, "--quiet", cwd=tmp_path)  # with its overlays: neither their bar nor the line shows
    assert quiet.returncode == 0 and "written: " not in quiet.stderr and "overlay" not in quiet.stderr


# ---- the suite's own warnings ----


def test_rre_at_gimbal_lock_is_the_peers_number_without_a_warning():
    import warnings

    from scipy.spatial.transform import Rotation

    from i2pbench.scoring.pose import pose_errors

    R = Rotation.from_euler("xzy", [10.0, 90.0, 20.0], degrees=True).as_matrix()  # z at 90 deg: locked
    T_pred = np.eye(4)
    T_pred[:3, :3] = R.T  # so that P_diff = inv(T_pred) @ I = R
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        errors = pose_errors(T_pred, np.eye(4))
    # at the lock only x + y is fixed: scipy gives x = 10 + 20, z = 90, y = 0, so RRE = 30 + 90 + 0
    assert errors.rre_deg == pytest.approx(120.0, abs=1e-6)
    assert errors.geodesic_deg == pytest.approx(np.degrees(Rotation.from_matrix(R).magnitude()))


# ---- a full disk under the runs folder ----


def test_a_full_disk_is_one_error_marks_the_invocation_failed_and_keeps_finished_frames(tmp_path, monkeypatch, capsys):
    import errno

    from i2pbench.cli import main
    from i2pbench.runs import store as store_module
    from i2pbench.runs.invocation import history

    require(KITTI)
    real, calls = store_module.pq.write_table, []

    def write_table(table, where, **kwargs):
        calls.append(where)
        if len(calls) > 2:  # two frames fit, the third finds the disk full half-way
            Path(where).write_bytes(b"PAR1")
            raise OSError(errno.ENOSPC, "No space left on device", str(where))
        return real(table, where, **kwargs)

    monkeypatch.setattr(store_module.pq, "write_table", write_table)
    runs = tmp_path / "runs"
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI_ROOT), *CLASSIC, "--frames", "4"]
    assert main([*args, "--runs-dir", str(runs), "--quiet"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    frames = runs / "kitti-all" / "frames"
    assert error.startswith(f"i2pbench: error: {calls[2]}: No space left on device while storing results;")
    assert f"marked failed; 2 finished frame record(s) kept in {frames}" in error
    (meta,) = history(runs / "kitti-all")
    assert meta["status"] == "failed" and "No space left on device" in meta["error"]
    assert len(list(frames.glob("*.parquet"))) == 2 and not list(frames.glob(".*.tmp"))
