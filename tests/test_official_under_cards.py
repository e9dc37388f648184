"""The official sizes prepare their authors' inputs from the dataset's frame; a protocol card that already gave the
stages its own inputs (`Frame.inputs`) is refused by name, where the image used to be halved and cropped twice into
zero cells and camera axes turned as the LiDAR's."""

from __future__ import annotations

import numpy as np
import pytest

from i2pbench.errors import StageError
from i2pbench.protocol import Protocol
from i2pbench.registry.build import default_registry
from i2pbench.scoring import installed
from i2pbench.types import SensorFrame

K = np.array([[700.0, 0.0, 620.0], [0.0, 700.0, 188.0], [0.0, 0.0, 1.0]])
T_CL = np.array([[0.0, -1.0, 0.0, 0.06], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27], [0.0, 0.0, 0.0, 1.0]])
OFFICIAL_EXTRACTORS = [
    ("extractor2d", "corri2p-official-grid"),
    ("extractor3d", "corri2p-official-points"),
    ("extractor2d", "vp2p-match-official-grid"),
    ("extractor3d", "vp2p-match-official-points"),
    ("extractor2d", "deepi2p-official-grid"),
    ("extractor3d", "deepi2p-official-points"),
]


def sensor() -> SensorFrame:
    rng = np.random.default_rng(0)
    xyz = np.c_[rng.uniform(5, 40, 600), rng.uniform(-10, 10, 600), rng.uniform(-1.5, 1.0, 600)]
    points = np.c_[xyz, rng.uniform(0, 1, 600)].astype(np.float32)
    return SensorFrame("kitti", "00/000000", np.zeros((376, 1241, 3), np.uint8), points,
                       np.zeros(600, np.int16), K, T_CL)  # fmt: skip


def test_a_frame_names_the_card_whose_inputs_it_holds():
    assert Protocol().apply(sensor()).inputs == ""  # the dataset's frame, in LiDAR axes
    assert installed.find("vp2p-match").protocol(seed=0, dataset="kitti").apply(sensor()).inputs == "vp2p-match"
    assert Protocol(pose_frame="camera").apply(sensor()).inputs == "edgeregnet"  # camera axes alone count


@pytest.mark.parametrize(("kind", "name"), OFFICIAL_EXTRACTORS)
def test_an_official_extractor_refuses_a_cards_frame_by_name(kind, name):
    stage = default_registry().component(kind, name)()
    card_frame = installed.find("corri2p").protocol(seed=0, dataset="kitti").apply(sensor())
    with pytest.raises(
        StageError, match=r"protocol 'corri2p' gives the stages its own \(512 x 160 image, 40960 points"
    ):
        stage(card_frame)
    out = stage(Protocol().apply(sensor()))  # the dataset's own frame is prepared as before
    assert len(out.uv if kind == "extractor2d" else out.xyz) > 0
