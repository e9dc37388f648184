""".npy files read strictly: the preprocessed layouts hold every array as one, and a copy cut short by a dead link
must fail naming the file and how much of it is there, not as a numpy reshape error from deep inside a loader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DataError


def header(path: Path) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, bytes the file must hold) from a .npy header, without reading the array."""
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    try:
        with path.open("rb") as f:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(f)
            offset = f.tell()
    except (ValueError, OSError, SyntaxError) as exc:
        raise DataError(f"{path}: not a .npy file ({exc})") from None
    if dtype.hasobject:
        raise DataError(f"{path}: holds Python objects ({dtype}), not numbers")
    return tuple(shape), dtype, offset + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize


def load(path: Path) -> np.ndarray:
    """The array of a .npy file; refused, naming the file, when it is shorter than its header says."""
    shape, dtype, needed = header(path)
    size = path.stat().st_size
    if size < needed:
        raise DataError(f"{path}: truncated .npy: {size} of the {needed} bytes its header ({dtype}, shape "
                        f"{shape}) needs")  # fmt: skip
    return np.load(path, allow_pickle=False)
