"""The authors' CoFiI2P state-dict layout imports as the official size's weights: a state dict made in their layout
(the keys and shapes their code recorded in tests/data/reference/cofii2p, kernel dispositions included) round-trips
tensor for tensor into CoFiI2PNetwork, with or without DataParallel's `module.` prefix, the four unused modules
dropped and recorded; a wrong key or shape is refused by name."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from i2pbench_cofii2p.official.importer import PREFIX, SIZE, STAGE, import_official
from i2pbench_cofii2p.official.network import CoFiI2PNetwork

from i2pbench.api import WeightsError
from i2pbench.testing.recipe import recipe_state

REFERENCE = Path(__file__).parent / "data" / "reference" / "cofii2p"
UNUSED = ("img_encoder.backbone.fc.", "img_feature_layer.", "fine_img_pos_encoding.", "fine_pc_pos_encoding.")


@pytest.fixture(scope="module")
def authors_state() -> dict[str, torch.Tensor]:
    state, _ = recipe_state(json.loads((REFERENCE / "state_dict_shapes.json").read_text()), "import")
    with np.load(REFERENCE / "inputs.npz") as inputs:
        kernels = {k: torch.from_numpy(inputs[k]) for k in inputs.files if k.endswith("kernel_points")}
    assert len(kernels) == 14  # one KPConv in each of the 14 blocks
    return state | kernels


@pytest.fixture(scope="module")
def saved(tmp_path_factory, authors_state) -> Path:
    path = tmp_path_factory.mktemp("cofii2p") / "cofii2p_kitti.t7"
    torch.save(authors_state, path)
    return path


def test_a_state_dict_in_the_authors_layout_round_trips(saved, authors_state):
    imported = import_official(saved)
    assert imported.size == SIZE and list(imported.state) == [STAGE]
    net = CoFiI2PNetwork()
    net.load_state_dict({k.removeprefix(PREFIX): v for k, v in imported.state[STAGE].items()})
    loaded = net.state_dict()
    kept = {k: v for k, v in authors_state.items() if not k.startswith(UNUSED)}
    assert set(loaded) == set(kept)
    assert all(torch.equal(loaded[k], v) for k, v in kept.items())
    assert imported.meta["dropped"] == sorted(k for k in authors_state if k.startswith(UNUSED))
    assert imported.trained_on["release"].endswith("trained on: KITTI Odometry sequences 00-08")


def test_dataparallel_prefixes_are_stripped(tmp_path, authors_state, saved):
    path = tmp_path / "cofii2p_nuscenes.t7"
    torch.save({"module." + k: v for k, v in authors_state.items()}, path)
    imported = import_official(path)
    plain = import_official(saved)
    assert list(imported.state[STAGE]) == list(plain.state[STAGE])
    assert imported.meta["dropped"] == plain.meta["dropped"]
    assert imported.trained_on["release"].endswith("trained on: nuScenes v1.0 trainval")


def test_a_wrong_key_or_shape_is_refused_by_name(tmp_path, authors_state):
    renamed = dict(authors_state)
    renamed["pc_encoder.encoder2_1.KPConv.weight"] = renamed.pop("pc_encoder.encoder2_1.KPConv.weights")
    torch.save(renamed, tmp_path / "renamed.t7")
    with pytest.raises(WeightsError, match=r"renamed\.t7 is not a state dict of the authors' CoFiI2P network: "
                       r"missing key net\.pc_encoder\.encoder2_1\.KPConv\.weights; unexpected key "
                       r"net\.pc_encoder\.encoder2_1\.KPConv\.weight$"):  # fmt: skip
        import_official(tmp_path / "renamed.t7")
    turned = dict(authors_state)
    turned["transformer.layers.3.merge.weight"] = torch.zeros(64, 128)
    torch.save(turned, tmp_path / "turned.t7")
    with pytest.raises(WeightsError, match=r"key net\.transformer\.layers\.3\.merge\.weight: shape \(64, 128\), "
                       r"expected \(128, 128\)"):  # fmt: skip
        import_official(tmp_path / "turned.t7")


def test_a_file_without_a_state_dict_is_refused(tmp_path):
    (tmp_path / "notes.t7").write_text("not a checkpoint")
    with pytest.raises(WeightsError, match="notes.t7 is a text file, not a torch file of tensors"):
        import_official(tmp_path / "notes.t7")
