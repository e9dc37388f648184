"""The embedded dataset is the same bytes on every machine: content hashes of frames of each split and style.

The hashes are of what a reader sees (the points' float32 bytes, the rings, the decoded RGB pixels), not of PNG
files. They were made on an AVX-512 machine; on a machine without it the pinned kernels (pinned.py) must give the
same. A failure here means the generator's output changed: if that was meant, bump GENERATOR_VERSION (so old caches
regenerate) and put the new hashes here; if not, something reached the frames that depends on the machine.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import numpy as np
import pytest

from i2pbench.data.synthetic import pinned
from i2pbench.data.synthetic.kitti_writer import simulate_here
from i2pbench.data.synthetic.rig import calib_text
from i2pbench.data.synthetic.style import STYLES

# (style, sequence, index) -> sha256 prefixes of (points, rings, pixels); frame 0 of train, val and test
HASHES = {
    ("default", "00", 0): ("30d600596c604d1f", "b15684f1b517a864", "b9eef904241b4971"),
    ("default", "01", 0): ("72fff07123d1a03f", "adb87a4b2cfb92ed", "b406344586663eab"),
    ("default", "02", 0): ("d60456797ba4ef9f", "e8e120e7a1924ec6", "99aab0baab92be63"),
    ("kitti", "00", 0): ("bb833c67a69982df", "bc1b8dd517e99cb7", "35ea80b21f0df261"),
    ("kitti", "01", 0): ("923628eb0a9a3222", "089919959dd57359", "f3f65bb97197a9b3"),
    ("kitti", "02", 0): ("c8a2b9e4ca0a19d6", "8fb031fbcdb0f353", "8a78bd534dfa2b52"),
}
# KITTI sequence 00's Tr with its rotation made orthonormal in Python floats (rig._orthonormal)
TR_LINE = (
    "Tr: 4.276798331443e-04 -9.999672285049e-01 -8.084491711955e-03 -1.198459927713e-02 -7.210626618910e-03 "
    "8.081198540402e-03 -9.999413488270e-01 -5.403984729748e-02 9.999739116366e-01 4.859490003590e-04 "
    "-7.206934150252e-03 -2.921968648686e-01"
)
# What moved the frames on one machine before the kernels were pinned: NumPy without its AVX-512 loops, OpenBLAS's
# Haswell kernels, OpenCV without AVX2. The children must not care what their parent's environment asks for.
HOSTILE = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENCV_CPU_DISABLE": "AVX2",
}


def content_hashes(points: np.ndarray, ring: np.ndarray, image: np.ndarray) -> tuple[str, str, str]:
    arrays = (points.astype("<f4"), ring.astype("<i2"), np.ascontiguousarray(image, np.uint8))
    return tuple(hashlib.sha256(a.tobytes()).hexdigest()[:16] for a in arrays)


@pytest.fixture(scope="module")
def made() -> dict:
    frames = list(HASHES)
    calls = [(0, sequence, index, 1, STYLES[style]) for style, sequence, index in frames]
    return dict(zip(frames, pinned.run(simulate_here, calls, workers=2), strict=True))


@pytest.mark.parametrize("frame", list(HASHES), ids=lambda f: "-".join(map(str, f)))
def test_a_frame_is_the_same_bytes_on_every_machine(made, frame):
    assert content_hashes(*made[frame]) == HASHES[frame]


def test_calib_txt_is_the_same_text_on_every_machine():
    assert calib_text().splitlines()[-1] == TR_LINE


def test_the_parents_kernel_settings_do_not_reach_the_frames(made):
    """A parent asking for other kernels (the settings that moved frames before) gets the same bytes."""
    code = (
        "from i2pbench.data.synthetic import pinned\n"
        "from i2pbench.data.synthetic.kitti_writer import simulate_here\n"
        "from test_synthetic_hashes import content_hashes\n"
        "print(*content_hashes(*pinned.run(simulate_here, [(0, '02', 0, 1)])[0]))\n"
    )
    env = {**os.environ, **HOSTILE, "PYTHONPATH": os.path.dirname(__file__)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert tuple(out.stdout.split()) == HASHES["default", "02", 0]


def test_a_child_refuses_to_make_frames_with_numpys_cpu_specific_loops():
    """The check that NPY_DISABLE_CPU_FEATURES took: a child started without it says so and makes nothing."""
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    code = "from i2pbench.data.synthetic.pinned import _check_pinned; _check_pinned()"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    from numpy._core import _multiarray_umath as umath

    if not any(umath.__cpu_features__.get(name) for name in umath.__cpu_dispatch__):
        pytest.skip("this CPU has none of the features NumPy dispatches on: nothing to refuse")
    assert out.returncode != 0 and "NPY_DISABLE_CPU_FEATURES not applied" in out.stderr


def test_a_failing_frame_names_its_call_and_error():
    from i2pbench.errors import DataError

    with pytest.raises(DataError, match=r"simulate_here\(0, 'x1', 0\) failed: invalid literal for int"):
        pinned.run(simulate_here, [(0, "x1", 0)])
