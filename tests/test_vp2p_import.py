"""The authors' VP2P-Match checkpoint layout loads into the official network as it is: a state dict made in their
layout (the keys and shapes their code recorded in tests/data/vp2p_reference) round-trips tensor for tensor with the
file's sha256 recorded, and a wrong key or shape is refused by name."""

import hashlib
import json
from pathlib import Path

import pytest
import torch
from i2pbench_vp2p_match.official.importer import RELEASE, load_official

from i2pbench.api import WeightsError
from i2pbench.testing.recipe import recipe_state

SHAPES = Path(__file__).parent / "data" / "vp2p_reference" / "state_dict_shapes.json"


@pytest.fixture(scope="module")
def authors_state():
    state, _ = recipe_state(json.loads(SHAPES.read_text()), "import")
    return state


def test_a_state_dict_in_the_authors_layout_round_trips(tmp_path, authors_state):
    path = tmp_path / "vp2p_kitti.pth"
    torch.save(authors_state, path)
    net, record = load_official(path)
    loaded = net.state_dict()
    assert list(loaded) == list(authors_state)
    assert all(torch.equal(loaded[k], v) for k, v in authors_state.items())
    assert record["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest() and record["release"] == RELEASE


def test_a_wrong_key_or_shape_is_refused_by_name(tmp_path, authors_state):
    renamed = dict(authors_state)
    renamed["voxel_branch.stem.0.weight"] = renamed.pop("voxel_branch.stem.0.kernel")
    torch.save(renamed, tmp_path / "renamed.pth")
    with pytest.raises(WeightsError, match=r"missing key voxel_branch\.stem\.0\.kernel.*unexpected key voxel_branch"):
        load_official(tmp_path / "renamed.pth")
    transposed = dict(authors_state)
    transposed["voxel_branch.stem.0.kernel"] = transposed["voxel_branch.stem.0.kernel"].transpose(1, 2)
    torch.save(transposed, tmp_path / "transposed.pth")
    wrong_shape = r"voxel_branch\.stem\.0\.kernel: shape \(27, 16, 7\), expected \(27, 7, 16\)"
    with pytest.raises(WeightsError, match=wrong_shape):
        load_official(tmp_path / "transposed.pth")


def test_a_file_without_a_state_dict_is_refused(tmp_path):
    (tmp_path / "notes.pth").write_text("not a checkpoint")
    with pytest.raises(WeightsError, match="notes.pth is a text file, not a torch file of tensors"):
        load_official(tmp_path / "notes.pth")
