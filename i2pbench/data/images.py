"""Camera images: read strictly, because OpenCV decodes a truncated JPEG without complaint.

A JPEG cut short decodes into an image whose lower part is grey; the frame then "succeeds" with a wrong pose
(a truncated nuScenes CAM_FRONT gave RTE 0.63 m instead of 0.09 m). So a JPEG must end with its end-of-image
marker and a PNG with its IEND chunk before it is decoded. Bytes after that marker (zero padding, another file
appended by a bad copy) are no truncation: the image before them is read.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import DataError

JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"
PNG_START = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk: zero length, type, CRC


def image_end(data: bytes) -> tuple[int | None, str]:
    """(length of the image proper, why it is cut short) of a JPEG or PNG: bytes after its end marker are not the
    image's (padding, a second file appended) and are not a truncation. (len(data), "") for other formats."""
    if data.startswith(JPEG_START):
        return _jpeg_end(data)
    if data.startswith(PNG_START):
        return _png_end(data)
    return len(data), ""


def _jpeg_end(data: bytes) -> tuple[int | None, str]:
    """The end-of-image marker is the first FF D9 after the first scan begins: scan data stuffs every FF byte, and
    the segments before the scan are walked by their lengths (an EXIF thumbnail there carries an FF D9 of its own)."""
    at = 2
    while at + 4 <= len(data) and data[at] == 0xFF and data[at + 1] != 0xDA:  # up to the start of scan
        at += 2 + int.from_bytes(data[at + 2 : at + 4], "big") if data[at + 1] != 0xFF else 1
    if at + 4 <= len(data) and data[at] == 0xFF:
        end = data.find(JPEG_END, at)
        return (end + 2, "") if end >= 0 else (None, "truncated JPEG (no end-of-image marker FF D9 at the end)")
    if data.rstrip(b"\x00").endswith(JPEG_END):  # headers this walk cannot follow: trust an end marker at the end
        return len(data), ""
    return None, "truncated JPEG (no end-of-image marker FF D9 at the end)"


def _png_end(data: bytes) -> tuple[int | None, str]:
    """The end of the IEND chunk, walking the chunks by their lengths (length, type, data, CRC)."""
    at = len(PNG_START)
    while at + 12 <= len(data):
        length, kind = int.from_bytes(data[at : at + 4], "big"), data[at + 4 : at + 8]
        at += 12 + length
        if kind == b"IEND":
            return (at, "") if at <= len(data) else (None, "truncated PNG (no IEND chunk at the end)")
    return None, "truncated PNG (no IEND chunk at the end)"


def truncation(data: bytes) -> str | None:
    """Why `data` is a truncated JPEG or PNG, or None when its end marker is there (other formats: None)."""
    return image_end(data)[1] or None


MAX_SIDE = 16384  # px; a camera image past this is no camera's (a 40k x 40k PNG took 7 GB to decode)


def header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from a PNG's IHDR or a JPEG's start-of-frame header, without decoding; None otherwise."""
    if data.startswith(PNG_START) and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not data.startswith(JPEG_START):
        return None
    at = 2
    while at + 9 <= len(data) and data[at] == 0xFF:
        marker, length = data[at + 1], int.from_bytes(data[at + 2 : at + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # a start of frame (not DHT, JPG, DAC)
            return int.from_bytes(data[at + 7 : at + 9], "big"), int.from_bytes(data[at + 5 : at + 7], "big")
        at += 2 + length
    return None


def check_fits(path: Path, image: np.ndarray, K: np.ndarray, calib: str | Path) -> None:
    """Refuse an image whose size does not fit the camera's intrinsics: its principal point must lie in the middle
    half of the image (a half-size image put it at the right edge and still 'registered', to RTE 3.37 m)."""
    height, width = image.shape[:2]
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (width / 4 < cx < 3 * width / 4 and height / 4 < cy < 3 * height / 4):
        raise DataError(
            f"{path}: the image is {width} x {height} px, but the intrinsics of {calib} put the principal point at "
            f"({cx:.1f}, {cy:.1f}), outside its middle half: the image does not fit this calibration (resized or "
            "cropped?)"
        )


def read_image(path: Path) -> np.ndarray:
    """[H x W x 3] uint8 RGB."""
    if not path.is_file():
        raise DataError(f"{path}: image not found")
    data = path.read_bytes()
    if not data:
        raise DataError(f"{path}: empty file (0 bytes), not an image")
    end, problem = image_end(data)
    if problem:
        raise DataError(f"{path}: {problem}")
    data = data[:end]  # what follows the end marker is no part of the image
    size = header_size(data)
    if size is not None and max(size) > MAX_SIDE:
        raise DataError(f"{path}: the image is {size[0]} x {size[1]} px, past {MAX_SIDE} px a side; not decoding it")
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None or bgr.size == 0:
        raise DataError(f"{path}: unreadable or corrupt image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
