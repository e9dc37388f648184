"""Issue 31's weak list, data readers: bytes after an image's end marker are not a truncation, an empty image names
its path, KITTI files in upper case are named instead of skipped, and nuScenes tables that lack a camera's record,
name a file outside the dataroot, or miss an ego pose or a whole table fail naming the table and the record."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import require
from test_data_bad_input import KITTI, RECORDS, SAMPLE, needs_kitti, needs_nuscenes

from i2pbench.data.images import image_end, read_image
from i2pbench.data.kitti import read_frame, sequence_stems
from i2pbench.data.nuscenes import NuScenes
from i2pbench.data.nuscenes_dataroot import build_dataroot
from i2pbench.errors import DataError

# ---- images: trailing bytes, empty files ----


def _jpeg(image: np.ndarray, **params: int) -> bytes:
    flags = [v for k, x in params.items() for v in (getattr(cv2, k), x)]
    return cv2.imencode(".jpg", image, flags)[1].tobytes()


@pytest.fixture
def picture() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 255, (48, 64, 3), np.uint8)


@pytest.mark.parametrize("extra", [b"junk", b"\xff\xd9" * 3, b"IEND" + bytes(100)])
@pytest.mark.parametrize("ext", [".png", ".jpg", "progressive.jpg"])
def test_bytes_after_the_end_marker_are_read_past_not_called_truncated(picture, tmp_path, ext, extra):
    data = (
        _jpeg(picture, IMWRITE_JPEG_PROGRESSIVE=1)
        if ext.startswith("progressive")
        else cv2.imencode(ext, picture)[1].tobytes()
    )
    clean, padded = tmp_path / f"clean{ext}", tmp_path / f"padded{ext}"
    clean.write_bytes(data)
    padded.write_bytes(data + extra)
    assert image_end(data + extra) == (len(data), "")
    assert np.array_equal(read_image(padded), read_image(clean))


@needs_kitti
def test_a_real_kitti_png_with_a_second_file_appended_still_reads(tmp_path):
    source = KITTI / "image_2" / "000000.png"
    doubled = tmp_path / "doubled.png"
    doubled.write_bytes(source.read_bytes() * 2)  # a bad copy that appended the file to itself
    assert np.array_equal(read_image(doubled), read_image(source))


def test_a_cut_jpeg_is_still_truncated_though_its_thumbnail_ends_with_ff_d9(picture, tmp_path):
    """An EXIF thumbnail carries an end marker of its own before the main image's scan: it must not count."""
    main, thumb = _jpeg(picture), _jpeg(picture[::4, ::4])
    app1 = b"\xff\xe1" + (len(thumb) + 8).to_bytes(2, "big") + b"Exif\0\0" + thumb
    whole = main[:2] + app1 + main[2:]
    path = tmp_path / "cut.jpg"
    path.write_bytes(whole[: len(whole) - 200])
    with pytest.raises(DataError, match=rf"{path}: truncated JPEG \(no end-of-image marker FF D9 at the end\)"):
        read_image(path)
    path.write_bytes(whole)
    assert np.array_equal(read_image(path), cv2.cvtColor(cv2.imdecode(np.frombuffer(main, np.uint8), 1), 4))


@pytest.mark.parametrize("cut", [8, 20, -13])
def test_a_png_cut_inside_its_chunks_is_truncated(picture, tmp_path, cut):
    data = cv2.imencode(".png", picture)[1].tobytes()
    path = tmp_path / "cut.png"
    path.write_bytes(data[:cut])
    with pytest.raises(DataError, match=rf"{path}: truncated PNG \(no IEND chunk at the end\)"):
        read_image(path)


@pytest.fixture
def seq(tmp_path) -> Path:
    """A one-frame copy of KITTI sequence 00."""
    require(KITTI)
    dst = tmp_path / "sequences" / "00"
    for rel in ("calib.txt", "velodyne/000000.bin", "image_2/000000.png"):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(KITTI / rel, dst / rel)
    return dst


def test_a_0_byte_png_is_an_error_naming_its_path(seq):
    image = seq / "image_2" / "000000.png"
    image.write_bytes(b"")
    with pytest.raises(DataError, match=rf"^{image}: empty file \(0 bytes\), not an image$"):
        read_frame(seq, "000000")


@pytest.mark.parametrize(("folder", "name"), [("velodyne", "000001.BIN"), ("image_2", "000001.Png")])
def test_a_kitti_file_in_upper_case_is_named_not_silently_skipped(seq, folder, name):
    other = "000001.png" if folder == "velodyne" else "000001.bin"
    shutil.copyfile(seq / folder / f"000000{Path(name).suffix.lower()}", seq / folder / name)
    shutil.copyfile(seq / ("image_2" if folder == "velodyne" else "velodyne") / f"000000{Path(other).suffix}",
                    seq / ("image_2" if folder == "velodyne" else "velodyne") / other)  # fmt: skip
    with pytest.raises(DataError, match=rf"{seq / folder / name}: KITTI names these files \*\.(bin|png), in lower"):
        sequence_stems(seq)


# ---- nuScenes tables ----


@pytest.fixture
def nus_root(tmp_path) -> Path:
    require(RECORDS)
    build_dataroot([RECORDS], tmp_path / "nuscenes")
    return tmp_path / "nuscenes"


def _edit(root: Path, table: str, edit) -> Path:
    path = root / "v1.0-trainval" / f"{table}.json"
    path.write_text(json.dumps(edit(json.loads(path.read_text()))))
    return path


def _front(rows: list[dict]) -> dict:
    return next(d for d in rows if "__CAM_FRONT__" in d["filename"])


def _load_error(root: Path, frame: str = f"{SAMPLE}/CAM_FRONT", **conf) -> str:
    dataset = NuScenes("val", {"root": str(root), **conf})
    assert frame in dataset.frame_ids()  # listed: the frame fails, named, instead of vanishing from the split
    with pytest.raises(DataError) as info:
        dataset.load(frame)
    return str(info.value)


@needs_nuscenes
def test_a_sample_without_its_camera_record_fails_that_frame_naming_table_and_sample(nus_root):
    table = _edit(nus_root, "sample_data", lambda rows: [d for d in rows if d is not _front(rows)])
    message = _load_error(nus_root, cameras=["CAM_FRONT", "CAM_FRONT_LEFT"])
    assert message.startswith(f"{table}: no CAM_FRONT keyframe record for sample {SAMPLE} (it has CAM_BACK")
    left = NuScenes("val", {"root": str(nus_root), "cameras": ["CAM_FRONT_LEFT"]}).load(f"{SAMPLE}/CAM_FRONT_LEFT")
    assert left.image.shape == (900, 1600, 3)  # the sample's other cameras still load


@needs_nuscenes
@pytest.mark.parametrize("name", ["../../../../../../etc/passwd", "samples/../../outside.jpg", "/etc/passwd", ""])
def test_a_table_path_outside_the_dataroot_is_refused_naming_the_record(nus_root, name):
    token = {}

    def escape(rows):
        token["front"] = _front(rows)["token"]
        _front(rows)["filename"] = name
        return rows

    table = _edit(nus_root, "sample_data", escape)
    message = _load_error(nus_root)
    assert message == (
        f"{table}: record {token['front']} names the file {name!r}, which is not a path inside the dataroot "
        "(absolute, empty or through ..): refused"
    )


@needs_nuscenes
def test_an_upper_case_extension_in_the_tables_is_read_not_dropped(nus_root):
    def upper(rows):
        front = _front(rows)
        renamed = front["filename"][: -len(".jpg")] + ".JPG"
        os.rename(nus_root / front["filename"], nus_root / renamed)
        front["filename"] = renamed
        return rows

    _edit(nus_root, "sample_data", upper)
    dataset = NuScenes("val", {"root": str(nus_root)})
    assert dataset.frame_ids() == [f"{SAMPLE}/CAM_FRONT"]
    assert dataset.load(f"{SAMPLE}/CAM_FRONT").image.shape == (900, 1600, 3)


@needs_nuscenes
def test_a_missing_ego_pose_names_the_table_and_token(nus_root):
    token = {}

    def drop(rows):
        sample_data = json.loads((nus_root / "v1.0-trainval" / "sample_data.json").read_text())
        token["pose"] = _front(sample_data)["ego_pose_token"]
        return [r for r in rows if r["token"] != token["pose"]]

    table = _edit(nus_root, "ego_pose", drop)
    assert _load_error(nus_root).startswith(f"{table}: no record with token {token['pose']} (named by sample_data ")


@needs_nuscenes
@pytest.mark.parametrize("table", ["ego_pose", "sample_data", "map"])
def test_a_missing_table_is_named(nus_root, table):
    path = nus_root / "v1.0-trainval" / f"{table}.json"
    path.unlink()
    with pytest.raises(DataError, match=rf"^{path} not found \(the devkit needs all 13 tables of v1.0-trainval\)$"):
        NuScenes("val", {"root": str(nus_root)}).frame_ids()
