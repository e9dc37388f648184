"""Bad input data: broken calibration or a truncated image is a DataError naming the file; whatever a dataset's
`load` raises fails that frame only, named, and the run goes on. Broken copies of the real frames live in tmp_path."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import toy_plugin
from conftest import SAMPLE_DATA, needs_sample
from conftest import needs_nuscenes as nuscenes_mark

from i2pbench.data.images import read_image
from i2pbench.data.kitti import read_frame
from i2pbench.data.nuscenes import NuScenes
from i2pbench.data.nuscenes_dataroot import build_dataroot
from i2pbench.errors import DataError
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

DATA = SAMPLE_DATA
KITTI = DATA / "kitti_odometry" / "sequences" / "00"
RECORDS = DATA / "nuscenes_records"
SAMPLE = "b5989651183643369174912bc5641d3b"
needs_kitti = needs_sample("kitti_odometry", "sequences", "00")
needs_nuscenes = nuscenes_mark()  # test_issue31_* import it from here


def _raises(path: Path, fn, *args) -> str:
    with pytest.raises(DataError) as info:
        fn(*args)
    assert str(path) in str(info.value)
    return str(info.value)


# ---- KITTI calibration ----


@pytest.fixture
def seq(tmp_path) -> Path:
    """A one-frame copy of sequence 00, to break."""
    dst = tmp_path / "sequences" / "00"
    for rel in ("calib.txt", "velodyne/000000.bin", "image_2/000000.png"):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(KITTI / rel, dst / rel)
    return dst


def _set_line(calib: Path, key: str, edit) -> None:
    """Rewrite the 12 values of line `key` with edit([3 x 4] matrix) -> [3 x 4] matrix or strings."""
    lines = []
    for line in calib.read_text().splitlines():
        if line.startswith(f"{key}:"):
            values = edit(np.array(line.split(":")[1].split(), dtype=object).reshape(3, 4))
            line = f"{key}: " + " ".join(str(v) for v in np.asarray(values).ravel())
        lines.append(line)
    calib.write_text("\n".join(lines) + "\n")


def _with(matrix, rows, cols, values):
    out = np.array(matrix, dtype=object)
    out[rows, cols] = values
    return out


@needs_kitti
@pytest.mark.parametrize(
    "K, message",
    [
        ([[0, 0, 609.6], [0, 0, 172.9], [0, 0, 1]], "fx=0, fy=0; both must be positive"),
        ([[1, 2, 0], [2, 4, 0], [0, 0, 1]], "K is singular"),  # det = 1 * 4 - 2 * 2 = 0 with fx, fy > 0
    ],
)
def test_singular_K(seq, K, message):
    _set_line(seq / "calib.txt", "P2", lambda P: _with(P, slice(None), slice(0, 3), np.array(K, dtype=object)))
    assert message in _raises(seq / "calib.txt", read_frame, seq, "000000")


@needs_kitti
def test_binary_calib_txt(seq):
    calib = seq / "calib.txt"
    calib.write_bytes(b"\xff\xd8\x00\x10" + np.random.default_rng(0).bytes(400))  # 0xff is never UTF-8
    assert "not a text calibration file (byte 0 is not UTF-8 text)" in _raises(calib, read_frame, seq, "000000")


@needs_kitti
def test_nan_in_P2(seq):
    _set_line(seq / "calib.txt", "P2", lambda P: _with(P, 0, 0, "nan"))
    assert "P2 holds 1 NaN or inf value(s)" in _raises(seq / "calib.txt", read_frame, seq, "000000")


@needs_kitti
@pytest.mark.parametrize(
    "edit, message",
    [
        # R scaled by 1.1: R^T R = 1.21 I, so |R^T R - I| = 0.21
        (lambda R: R.astype(float) * 1.1, "|R^T R - I| = 0.21 > 0.001"),
        # first row negated: still orthonormal, but a reflection
        (lambda R: R.astype(float) * np.array([[-1.0], [1.0], [1.0]]), "det R = -1"),
    ],
)
def test_non_rigid_Tr(seq, edit, message):
    _set_line(seq / "calib.txt", "Tr", lambda T: np.c_[edit(T[:, :3]), T[:, 3]])
    message_seen = _raises(seq / "calib.txt", read_frame, seq, "000000")
    assert "the rotation of Tr is not a rotation" in message_seen and message in message_seen


# ---- nuScenes calibration records ----


@pytest.fixture
def nus_root(tmp_path) -> Path:
    """A fresh dataroot of the one real keyframe (links to shared/data, tables of its own)."""
    build_dataroot([RECORDS], tmp_path / "nuscenes")
    return tmp_path / "nuscenes"


@needs_nuscenes
@pytest.mark.parametrize("table", ["calibrated_sensor", "ego_pose"])
def test_nuscenes_zero_quaternion(nus_root, table):
    # broken before the devkit first reads the tables: it reads them once per (root, version)
    rows = json.loads((nus_root / "v1.0-trainval" / "sample_data.json").read_text())
    front = next(d for d in rows if "__CAM_FRONT__" in d["filename"])
    token = front[f"{table}_token"]
    path = nus_root / "v1.0-trainval" / f"{table}.json"
    path.write_text(json.dumps([{**r, "rotation": [0, 0, 0, 0]} if r["token"] == token else r
                                for r in json.loads(path.read_text())]))  # fmt: skip
    message = _raises(path, NuScenes("val", {"root": str(nus_root)}).load, f"{SAMPLE}/CAM_FRONT")
    assert f"token {token}: the rotation quaternion [0.0, 0.0, 0.0, 0.0] has zero norm" in message


@needs_nuscenes
def test_nuscenes_singular_camera_intrinsic(nus_root):
    path = nus_root / "v1.0-trainval" / "calibrated_sensor.json"
    rows = json.loads(path.read_text())
    for r in rows:
        if r["camera_intrinsic"]:
            r["camera_intrinsic"][0][0] = r["camera_intrinsic"][1][1] = 0.0
    path.write_text(json.dumps(rows))
    message = _raises(path, NuScenes("val", {"root": str(nus_root)}).load, f"{SAMPLE}/CAM_FRONT")
    assert "camera_intrinsic" in message and "fx=0, fy=0" in message


# ---- truncated images ----


@needs_nuscenes
def test_truncated_jpeg(nus_root):
    image = next((nus_root / "samples" / "CAM_FRONT").iterdir())
    data = image.read_bytes()
    image.unlink()  # a link into shared/data: replace it, never write through it
    image.write_bytes(data[: len(data) * 9 // 10])
    message = _raises(image, NuScenes("val", {"root": str(nus_root)}).load, f"{SAMPLE}/CAM_FRONT")
    assert "truncated JPEG" in message


@needs_kitti
def test_truncated_png(seq):
    image = seq / "image_2" / "000000.png"
    image.write_bytes(image.read_bytes()[:-1000])
    assert "truncated PNG (no IEND chunk at the end)" in _raises(image, read_frame, seq, "000000")


@needs_nuscenes
def test_jpeg_with_zero_padding_after_its_end_marker_still_reads(tmp_path):
    source = next(RECORDS.glob("*/*__CAM_FRONT__*.jpg"))
    padded = tmp_path / "padded.jpg"
    padded.write_bytes(source.read_bytes() + bytes(16))
    assert np.array_equal(read_image(padded), read_image(source))


# ---- any exception in a dataset's load: that frame fails, named; the others run ----


class Buggy(toy_plugin.ToyDataset):
    """A third-party reader with a bug on one frame: a plain ValueError, not a DataError."""

    name = "buggy"

    def frame_ids(self):
        return ["a", "broken", "c"]

    def load(self, frame_id):
        if frame_id == "broken":
            raise ValueError("cannot reshape array of size 13 into shape (4)")
        return super().load(frame_id)


class Singular(toy_plugin.ToyDataset):
    name = "singular"

    def load(self, frame_id):
        np.linalg.inv(np.zeros((3, 3)))


def test_a_plain_exception_in_load_fails_that_frame_and_the_run_goes_on(tmp_path, monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    base = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
    rows = run_grid(registry, [Combination(base)], Buggy("test"), Protocol(), ResultsStore(tmp_path))
    records = rows.set_index("frame_id")
    assert records.loc["broken", "status"] == "failed"
    assert records.loc["broken", "failed_component"] == "dataset 'buggy'"
    assert records.loc["broken", "error"] == (
        "dataset 'buggy' frame 'broken': ValueError: cannot reshape array of size 13 into shape (4)"
    )
    assert list(records.loc[["a", "c"], "status"]) == ["ok", "ok"]
    assert list(records.loc[["a", "c"], "n_kp3d"]) == [3, 3]


def test_every_caller_of_load_gets_a_data_error_and_data_errors_pass_unchanged():
    with pytest.raises(DataError, match="^dataset 'singular' frame 'a': LinAlgError: Singular matrix$") as info:
        Singular("test").load("a")
    assert isinstance(info.value.__cause__, np.linalg.LinAlgError)
    with pytest.raises(DataError, match="^/data/toy/bad.bin: size 13 is not a multiple of 16 bytes$"):
        Buggy("test").load("bad")  # the toy's own DataError, through two wrapped loads
