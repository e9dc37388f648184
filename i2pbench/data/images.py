"""Camera images: read strictly, because OpenCV decodes a truncated JPEG without complaint.

A JPEG cut short decodes into an image whose lower part is grey; the frame then "succeeds" with a wrong pose
(a truncated nuScenes CAM_FRONT gave RTE 0.63 m instead of 0.09 m). So a JPEG must end with its end-of-image
marker and a PNG with its IEND chunk before it is decoded.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import DataError

JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"
PNG_START = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the IEND chunk: zero length, type, CRC


def truncation(data: bytes) -> str | None:
    """Why `data` is a truncated JPEG or PNG, or None when its end marker is there (other formats: None)."""
    if data.startswith(JPEG_START) and not data.rstrip(b"\x00").endswith(JPEG_END):
        return "truncated JPEG (no end-of-image marker FF D9 at the end)"
    if data.startswith(PNG_START) and not data.endswith(PNG_END):
        return "truncated PNG (no IEND chunk at the end)"
    return None


def read_image(path: Path) -> np.ndarray:
    """[H x W x 3] uint8 RGB."""
    if not path.is_file():
        raise DataError(f"{path}: image not found")
    data = path.read_bytes()
    problem = truncation(data)
    if problem:
        raise DataError(f"{path}: {problem}")
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None or bgr.size == 0:
        raise DataError(f"{path}: unreadable or corrupt image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
