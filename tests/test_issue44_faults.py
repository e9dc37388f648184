"""Issue 44's faults on the newer surfaces (checkpoint import, environment records, limits, evaluate, signals): each
bad input is one clear error naming the file or option, nothing shipped or stored is overwritten or changed, and an
interrupted run keeps its finished frames and says how it ended."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import torch
from conftest import SAMPLE_DATA, needs_sample, require
from test_cli_errors import ROOT

from i2pbench.cli import main

SHIPPED = ROOT / "plugins" / "edgeregnet" / "i2pbench_edgeregnet" / "weights" / "edgeregnet-cpu-synthetic.pt"
SHAPES = SAMPLE_DATA / "edgeregnet_reference" / "state_dict_shapes.json"
needs_shapes = needs_sample("edgeregnet_reference", "state_dict_shapes.json")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cli(capsys, *args: str) -> tuple[int, str]:
    """`i2pbench ARGS` in this process: (exit status, the one error line or the whole stderr)."""
    status = main(list(args))
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if line.startswith("i2pbench: error:")]
    return status, errors[0] if len(errors) == 1 else err


@pytest.fixture(scope="module")
def official(tmp_path_factory) -> Path:
    """a file of the authors' AttentionModule keys and shapes (zeros), as `KITTI.t7` is laid out."""
    shapes = json.loads(SHAPES.read_text())
    path = tmp_path_factory.mktemp("official") / "good.t7"
    torch.save({key: torch.zeros(shape) for key, shape in shapes.items()}, path)
    return path


def _import(capsys, source: Path, out: Path, *extra: str) -> tuple[int, str]:
    return cli(capsys, "weights", "import", "edgeregnet-official", str(source), "--out", str(out), *extra)


@needs_shapes
def test_weights_import_never_overwrites_a_shipped_checkpoint_its_source_or_another_kind_of_file(
    official, tmp_path, capsys
):
    text = tmp_path / "notes.txt"
    text.write_text("my notes\n")
    for out, said in (
        (SHIPPED, "is inside the installed package"),
        (official, "is the file being imported"),
        (text, "exists and is no i2pbench checkpoint (checkpoint " + f"{text} is a text file"),
    ):
        before = sha256(out)
        assert _import(capsys, official, out, "--force") == (2, f"i2pbench: error: --out {out} {said}" + _rest(out))
        assert sha256(out) == before
    assert not list(SHIPPED.parent.glob(".*.tmp"))


def _rest(out: Path) -> str:
    """the end of each refusal above, after `--out OUT <what it is>`."""
    if out == SHIPPED:
        return (
            f" {SHIPPED.parent.parent}; the import never writes there (shipped weights and code). Write to another "
            "path and copy the result if you mean to ship it"
        )
    if out.suffix == ".txt":
        return (
            ", not an i2pbench checkpoint); the import never overwrites it. Give another --out, or move that file aside"
        )
    return "; the import never overwrites its source"


@needs_shapes
def test_weights_import_replaces_its_own_kind_only_with_force_and_errors_name_the_users_path(
    official, tmp_path, capsys
):
    out = tmp_path / "W.pt"
    assert _import(capsys, official, out)[0] == 0
    first = sha256(out)
    assert _import(capsys, official, out) == (
        2,
        f"i2pbench: error: --out {out} is an existing checkpoint; the import would replace it. Give a new --out, or "
        "--force to replace it",
    )
    assert sha256(out) == first
    assert _import(capsys, official, out, "--force")[0] == 0
    assert sha256(out) != first  # a new date in the record: rewritten
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert _import(capsys, official, blocker / "W.pt") == (
        2,
        f"i2pbench: error: checkpoint {blocker / 'W.pt'} could not be written: {blocker}: a file is there where a "
        "folder is needed",
    )
    assert _import(capsys, official, tmp_path) == (
        2,
        f"i2pbench: error: --out {tmp_path} is a folder; give a checkpoint file path (e.g. {tmp_path / 'mine.pt'})",
    )


@needs_shapes
def test_weights_import_refuses_values_that_are_not_finite_floats_and_keys_that_are_not_strings(
    official, tmp_path, capsys
):
    state = torch.load(official, weights_only=True)
    key = "superpoint.conv1a.weight"  # encoder2d's conv1a.weight, 64 x 1 x 3 x 3 = 576 values
    nan = state[key].clone()
    nan[0, 0, 1, 2] = float("nan")
    bad = {
        "nan": (nan, "holds 1 NaN or infinite value(s) of 576"),
        "inf": (torch.full_like(state[key], float("inf")), "holds 576 NaN or infinite value(s) of 576"),
        "bool": (state[key].bool(), "is bool, not floating point"),
        "int": (state[key].int(), "is int32, not floating point"),
        "complex": (state[key].to(torch.complex64), "is complex64, not floating point"),
    }
    for name, (value, said) in bad.items():
        source = tmp_path / f"{name}.t7"
        torch.save({**state, key: value}, source)
        assert _import(capsys, source, tmp_path / "W.pt") == (
            2,
            f"i2pbench: error: {source}: not finite floating-point weights for encoder2d 'superpoint-official': "
            f"conv1a.weight {said}",
        )
    source = tmp_path / "intkey.t7"
    torch.save({**state, 5: torch.zeros(1)}, source)
    assert _import(capsys, source, tmp_path / "W.pt") == (
        2,
        f"i2pbench: error: {source}: key 5 (int) is not a parameter name (a string)",
    )
    assert not (tmp_path / "W.pt").exists()


class _Code:
    def __reduce__(self):
        return (print, ("this never runs",))


@pytest.mark.parametrize("importer", ["corri2p-official", "deepi2p-official", "vp2p-match-official"])
def test_every_official_importer_reads_through_the_one_checked_reader(importer, tmp_path, capsys):
    """the official sizes landed after the reader: a non-string key, a text file and an empty file are refused by
    each importer as by edgeregnet-official, naming the file, before any key of the authors' layout is checked."""
    intkey, text, empty = tmp_path / "intkey.pth", tmp_path / "notes.pth", tmp_path / "empty.pth"
    torch.save({"conv.weight": torch.zeros(1), 5: torch.zeros(1)}, intkey)
    text.write_text("my notes\n")
    empty.touch()
    said = {
        intkey: f"{intkey}: key 5 (int) is not a parameter name (a string)",
        text: f"{text} is a text file, not a torch file of tensors",
        empty: f"{empty} is empty (0 bytes), not a torch file",
    }
    for source, message in said.items():
        out = tmp_path / "W.pt"
        assert cli(capsys, "weights", "import", importer, str(source), "--out", str(out)) == (
            2,
            f"i2pbench: error: {message}",
        )
        assert not out.exists()


def test_unreadable_sources_say_what_they_are_and_never_advise_running_their_code(tmp_path, capsys):
    (tmp_path / "empty.t7").write_bytes(b"")
    (tmp_path / "text.t7").write_text("epoch 1 loss 0.3\n")
    (tmp_path / "folder.t7").mkdir()
    torch.save({"conv1a.weight": _Code()}, tmp_path / "code.t7")
    said = {
        "empty.t7": "is empty (0 bytes), not a torch file",
        "text.t7": "is a text file, not a torch file of tensors",
        "folder.t7": "is a folder, not a file",
        "code.t7": "is not a readable torch file: it holds Python objects, not only tensors (not a file i2pbench "
        "wrote), and is not unpickled",
    }
    for name, what in said.items():
        status, error = _import(capsys, tmp_path / name, tmp_path / "W.pt")
        assert (status, error) == (2, f"i2pbench: error: {tmp_path / name} {what}")
        assert "weights_only" not in error
    from i2pbench.errors import WeightsError
    from i2pbench.weights.checkpoints import load_init

    for name, what in said.items():  # `train --init-2d`'s reader says the same
        with pytest.raises(WeightsError) as caught:
            load_init(torch.nn.Linear(1, 1), tmp_path / name)
        assert str(caught.value) == f"{tmp_path / name} {what}"


@needs_shapes
def test_train_init_2d_with_a_nan_says_so_instead_of_blaming_the_learning_rate(official, tmp_path, capsys):
    state = torch.load(official, weights_only=True)
    superpoint = {k.removeprefix("superpoint."): v for k, v in state.items() if k.startswith("superpoint.")}
    superpoint["convDb.bias"] = torch.full_like(superpoint["convDb.bias"], float("nan"))
    init = tmp_path / "superpoint_v1.pth"
    torch.save(superpoint, init)
    out = tmp_path / "W.pt"
    status, error = cli(
        capsys, "train", "--preset", "edgeregnet-official", "--out", str(out), "--init-2d", str(init), "--steps", "1",
        "--data-root", str(tmp_path / "synthetic"),
    )  # fmt: skip
    assert (status, error) == (
        2,
        f"i2pbench: error: {init}: not finite floating-point weights for encoder2d 'superpoint-official': "
        "convDb.bias holds 256 NaN or infinite value(s) of 256",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["superpoint_v1.pth"]  # no checkpoint, log or data


MALFORMED_RECORDS = {  # .env.json text -> what the warning says is wrong with it
    "[1, 2]": "is not an environment record: a JSON array, not an object",
    '{"invocations": "notalist"}': "is not an environment record: 'invocations' is a string, not an array",
    '[{"environment": "x"}]': "is not an environment record: a JSON array, not an object",
    '{"invocations": [{"environment": "x"}]}': "is not an environment record: invocations[0].environment is a "
    "string, not an object",
    '{"invocations": [{"environment": {"packages": [1]}}]}': "is not an environment record: "
    "invocations[0].environment.packages is not an object",
    '{"invocations": [3]}': "is not an environment record: invocations[0] is a number, not an object",
    "{not json": "is not JSON (JSONDecodeError: Expecting property name enclosed in double quotes: line 1 column 2 "
    "(char 1))",
}


def test_compare_and_table_warn_on_a_malformed_environment_record_and_never_call_it_a_regression(tmp_path, capsys):
    from test_compare_environment import _board

    new, base = _board(tmp_path, "new"), _board(tmp_path, "base")
    record = tmp_path / "base.env.json"
    for text, problem in MALFORMED_RECORDS.items():
        record.write_text(text)
        assert main(["compare", str(new), str(base)]) == 0  # the boards agree: no regression
        captured = capsys.readouterr()
        assert "Traceback" not in captured.err
        assert captured.out.endswith("OK: 1 rows compared, 0 regressed, 0 missing, 0 new\n")
        assert captured.err.splitlines() == [
            f"i2pbench: warning: baseline {base}: its environment record {record} {problem}; its package and "
            "generator versions are unknown, so a difference in them would go unnoticed"
        ]
        assert main(["table", "--preset", "classic-oracle", f"KITTI={new}", f"nuScenes={base}"]) == 0
        assert capsys.readouterr().err.splitlines() == [
            f"i2pbench: warning: nuScenes {base}: its environment record {record} {problem}; its package and "
            "generator versions are unknown, so a difference in them would go unnoticed"
        ]


def test_table_warns_as_compare_does_on_boards_from_other_versions(tmp_path, capsys):
    from test_compare_environment import _board

    kitti, nuscenes = _board(tmp_path, "kitti"), _board(tmp_path, "nus", numpy="2.3.1", generator=6)
    assert main(["table", "--preset", "classic-oracle", f"KITTI={kitti}", f"nuScenes={nuscenes}"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "i2pbench: warning: the boards come from different numpy versions: 2.4.6 (KITTI) vs 2.3.1 (nuScenes); a "
        "difference in results may come from it, not from the code",
        "i2pbench: warning: the boards come from different synthetic generator versions (generator_version): 5 "
        "(KITTI) vs 6 (nuScenes); a difference in results may come from it, not from the code",
    ]
    (tmp_path / "nus.env.json").unlink()
    assert main(["table", "--preset", "classic-oracle", f"KITTI={kitti}", f"nuScenes={nuscenes}"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"i2pbench: warning: nuScenes {nuscenes} has no environment record (nus.env.json beside it, or its run's "
        "store): its package and generator versions are unknown, so a difference in them would go unnoticed"
    ]


def _dead_pid() -> int:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def _made(root: Path, **frames: int) -> None:
    """sequences as the generator leaves them, complete (marker written), with `frames` frames each."""
    from i2pbench.data.synthetic.dataset import MARKER, SPLIT_SEQUENCES, marker

    for split, n in frames.items():
        sequence = root / "sequences" / SPLIT_SEQUENCES[split]
        sequence.mkdir(parents=True)
        (sequence / MARKER).write_text(json.dumps(marker(0, SPLIT_SEQUENCES[split], n)))


def test_data_synth_is_bounded_and_sweeps_what_a_killed_generation_left(tmp_path, capsys):
    import os

    root = tmp_path / "synthetic"
    for option in ("--train", "--val", "--test"):  # refused by argparse, before any work or memory
        with pytest.raises(SystemExit) as stop:
            main(["data", "synth", "--root", str(root), option, "1000000000000"])
        assert stop.value.code == 2
        assert f"argument {option}: 1000000000000 frames: a split holds at most 50,000" in capsys.readouterr().err
    assert not root.exists()
    _made(root, train=0, val=0, test=0)
    sequences = root / "sequences"
    killed, old, live, young = (sequences / name for name in (".00-killed", ".old-noowner", ".01-live", ".02-young"))
    for folder in (killed, old, live, young):
        (folder / "00" / "velodyne").mkdir(parents=True)
    (killed / "owner.pid").write_text(str(_dead_pid()))
    (live / "owner.pid").write_text(str(os.getpid()))  # a concurrent generation in progress: kept
    os.utime(old, (0, 0))  # made before owners were recorded, long ago; `young` may be one just starting
    assert main(["data", "synth", "--root", str(root), "--train", "0", "--val", "0", "--test", "0", "--quiet"]) == 0
    assert sorted(p.name for p in sequences.iterdir()) == [".01-live", ".02-young", "00", "01", "02"]


def test_train_refuses_a_validation_split_with_no_frames_before_writing_anything(tmp_path, capsys):
    root = tmp_path / "synthetic"
    _made(root, val=0)
    out = tmp_path / "w" / "W.pt"
    status, error = cli(
        capsys, "train", "--data-root", str(root), "--data-conf", "frames.val=0", "--out", str(out), "--steps", "1"
    )
    assert (status, error) == (
        2,
        f"i2pbench: error: {root / 'sequences' / '01' / 'velodyne'}: empty sequence (no .bin scans)",
    )
    assert not out.parent.exists()  # no checkpoint, resume file or OUT.log.jsonl
    assert sorted(p.name for p in (root / "sequences").iterdir()) == ["01"]  # the train split was never made


DATA = SAMPLE_DATA
needs_drives = needs_sample("kitti_drives", "sequences", "33")
SPLIT = """name: mysplit
scenes:
  a: [kitti_drives/33]
  b: [kitti_drives/30]
  c: [kitti_drives/39]
train: [{train}]
val: [{val}]
test: [c]
"""


def _run(capsys, runs: Path, *args: str) -> None:
    assert main(["run", "--dataset", "kitti-drives", "--data-root", str(DATA), "--split", "test", "--preset",
                 "classic-oracle", "--runs-dir", str(runs), "--quiet", *args]) == 0  # fmt: skip
    capsys.readouterr()


@needs_drives
def test_evaluate_reads_without_changing_the_store_and_refuses_what_it_cannot_count(tmp_path, capsys):
    runs = tmp_path / "runs"
    for train, val in (("a", "b"), ("b", "a")):  # two split files of one name: one store, other data
        split = tmp_path / f"split-{train}.yaml"
        split.write_text(SPLIT.format(train=train, val=val))
        _run(capsys, runs, "--split-file", str(split))
    store = runs / "kitti-drives-test-mysplit"
    assert len(list((store / "frames").glob("*.parquet"))) == 4  # the test scene's 2 frames, once per split file
    status, error = cli(capsys, "evaluate", str(store), "--invocation", "all")
    assert status == 2 and error.startswith(
        f"i2pbench: error: {store}: 2 frame(s) of a row are recorded more than once (e.g. frame 39/"
    )
    assert "split files with one name:" in error and error.endswith("Evaluate one run's grid with --invocation ID")
    assert main(["evaluate", str(store)]) == 0  # the last run's grid alone: its 2 frames
    assert "\n2 per-frame records of the grid's 2;" in capsys.readouterr().err
    from i2pbench.runs.evaluate import evaluate
    from i2pbench.runs.invocation import history

    assert set(evaluate(store).records["invocation"]) == {history(store)[-1]["id"]}  # its own, not the other data's

    old = store / "frames" / "0123456789abcdef01234567.parquet"  # a record of an older schema (no pose errors)
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.Table.from_pylist([{"dataset": "kitti-drives", "frame_id": "39/000000"}]), old)
    before = {p.name: sha256(p) for p in (store / "frames").iterdir()}
    assert main(["evaluate", str(store)]) == 0
    err = capsys.readouterr().err
    assert f"i2pbench: warning: malformed result {old} (SchemaError: " in err
    assert "skipped, left as it is (a run sets it aside and computes the frame again)" in err
    assert {p.name: sha256(p) for p in (store / "frames").iterdir()} == before  # nothing renamed, swept or made

    assert cli(capsys, "evaluate", str(store), "--rules", ",") == (
        2,
        "i2pbench: error: --rules ',' names no protocol card; give names (edgeregnet, corri2p, deepi2p, vp2p-match, "
        "cofii2p, icl) or all",
    )
    missing = tmp_path / "runs" / "kitti-drives-tset"
    assert cli(capsys, "evaluate", str(missing)) == (
        2,
        f"i2pbench: error: {missing} does not exist (give a folder `i2pbench run` wrote, such as "
        "runs/<dataset>-<split>)",
    )
    assert not missing.exists()
    board = runs / "leaderboards" / "kitti-drives-test-mysplit-classic-oracle.csv"
    assert cli(capsys, "evaluate", str(board)) == (
        2,
        f"i2pbench: error: {board} is a file, not a folder `i2pbench run` wrote (such as runs/<dataset>-<split>)",
    )


@needs_drives
def test_report_draws_overlays_for_a_kitti_drives_fold_run(tmp_path, capsys):
    runs = tmp_path / "runs"
    _run(capsys, runs, "--fold", "1/5", "--frames", "2")
    store = runs / "kitti-drives-test-fold1of5"
    out = tmp_path / "report.html"
    assert main(["report", str(store), "--overlays", "1", "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "overlays left out" not in err, err
    assert out.read_text().count("<img") >= 2  # the best and the worst frame of the top row

    from i2pbench.data.kitti_drives import KittiDrives

    recorded = {"name": "kitti-real-drives", "sha256": "0" * 64}  # the run's split file, since edited
    with pytest.raises(Exception, match=r"has sha256 [0-9a-f]{12}, not the run's 000000000000: its scenes changed"):
        KittiDrives("test", {"root": str(DATA), "split_file": recorded})


LAUNCHER = """
import sys
sys.path.insert(0, {tests!r})
if __name__ == "__main__":
    import stall_always
    import test_issue31_interrupt
    from i2pbench.cli import main
    from i2pbench.registry import build

    registry = build.build_registry((test_issue31_interrupt.StallPlugin(), stall_always.StallAlwaysPlugin()))
    build.default_registry = lambda: registry
    sys.exit(main())
"""


def _stopped_run(tmp_path: Path, sig: int, extractor: str, *extra: str):
    """`i2pbench run` over the 6 KITTI frames with a stalling extractor, sent `sig` once a frame is stored
    (stall-after-first) or once the first frame started (stall-always): (the finished process, its store)."""
    import subprocess
    import sys
    import time

    from plugin_dists import default_sigint
    from test_report_html import KITTI

    require(KITTI)
    launcher, runs = tmp_path / "launch.py", tmp_path / "runs"
    launcher.write_text(LAUNCHER.format(tests=str(Path(__file__).resolve().parent)))
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI), "--extractor", extractor,
            "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac", "--runs-dir", str(runs),
            "--quiet", *extra]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, str(launcher), *args], cwd=tmp_path, text=True, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, preexec_fn=default_sigint,
    )  # fmt: skip
    ready = (
        (lambda: list((runs / "kitti-all" / "frames").glob("*.parquet")))
        if extractor == "stall-after-first"
        else (lambda: list(tmp_path.glob("started.*")))
    )
    deadline = time.monotonic() + 300  # a guard against a hang, not a timing assertion
    while not ready():
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"the run ended or hung before it was ready: {process.communicate()[1][-2000:]}")
        time.sleep(0.05)
    process.send_signal(sig)
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err), runs / "kitti-all"


def _record(store: Path) -> dict:
    (record,) = [json.loads(p.read_text()) for p in (store / "invocations").glob("*.json")]
    return record


@pytest.mark.parametrize("workers", [[], ["--workers", "2"]], ids=["serial", "pool"])
def test_sigterm_stops_a_run_as_ctrl_c_does(tmp_path, workers):
    import signal

    done, store = _stopped_run(tmp_path, signal.SIGTERM, "stall-after-first", *workers)
    assert done.returncode == 143, done.stderr  # 128 + SIGTERM, as a shell reports it
    assert "Traceback" not in done.stderr and "leaked" not in done.stderr, done.stderr  # no resource_tracker warning
    assert done.stderr.strip().splitlines()[-1] == (
        f"i2pbench: interrupted (SIGTERM): workers stopped; 1 of 6 frames finished (1 computed by this run), all "
        f"kept in {store / 'frames'}; the board above is of those; the same command resumes"
    )
    assert "| stall-after-first > depth" in done.stdout  # the board of the finished frame
    assert len(list((store / "frames").glob("*.parquet"))) == 1 and not list((store / "frames").glob(".*.tmp"))
    record = _record(store)
    assert record["status"] == "failed" and record["error"] == "interrupted by SIGTERM after 1 of 6 frames"


def test_ctrl_c_before_any_frame_finished_claims_no_board(tmp_path):
    import signal

    done, store = _stopped_run(tmp_path, signal.SIGINT, "stall-always")
    assert done.returncode == 130, done.stderr
    assert done.stdout == ""  # no board: nothing finished
    assert done.stderr.strip().splitlines()[-1] == (
        "i2pbench: interrupted (Ctrl-C): workers stopped; 0 of 6 frames finished (0 computed by this run), nothing "
        "to keep; the same command resumes"
    )
    assert _record(store)["error"] == "interrupted by Ctrl-C after 0 of 6 frames"


def test_ctrl_c_while_the_board_is_written_marks_the_invocation(tmp_path, capsys, monkeypatch):
    from test_report_html import KITTI

    require(KITTI)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt  # Ctrl-C as the board's files are written

    monkeypatch.setattr("i2pbench.boards.leaderboard.write", interrupted)
    runs = tmp_path / "runs"
    status = main(["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI), "--preset",
                   "classic-oracle", "--frames", "2", "--runs-dir", str(runs), "--quiet"])  # fmt: skip
    assert status == 130
    err = capsys.readouterr().err
    store = runs / "kitti-all"
    assert err.strip().splitlines()[-1] == (
        f"i2pbench: interrupted (Ctrl-C): workers stopped; 2 of 2 frames finished (2 computed by this run), all kept "
        f"in {store / 'frames'}; the board above is of those; the same command resumes"
    )
    record = _record(store)
    assert record["status"] == "failed" and record["error"] == "interrupted by Ctrl-C after 2 of 2 frames"
    assert not (runs / "leaderboards").exists() or not list((runs / "leaderboards").glob("*.csv"))
