"""The official size computes the authors' EdgeRegNet: on the reference vectors their `AttentionModule` produced
(folder from I2PBENCH_EDGEREGNET_REFERENCE, default ../shared/data/edgeregnet_reference), with its seeded weights
imported through `i2pbench weights import edgeregnet-official`, every recorded tensor agrees within 1e-4 of its
largest value, integer outputs exactly, and so do the authors' losses; a wrong head layout or an untied layer does
not. Nothing here assumes the particular set: another frame, `n` or salted recipe passes unchanged."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import SAMPLE_DATA
from i2pbench_edgeregnet.method import official_stages
from i2pbench_edgeregnet.official import importer
from i2pbench_edgeregnet.official.matching import official_loss, project
from i2pbench_edgeregnet.official.pointnet2 import ball_query, normalize
from i2pbench_edgeregnet.official.reference import reference_forward, reference_frame

from i2pbench.cli import main
from i2pbench.layers.pointnet2 import ball_query as fast_ball_query
from i2pbench.layers.pointnet2 import farthest_point_sampling
from i2pbench.testing.recipe import folder_state
from i2pbench.weights.checkpoints import load_checkpoint

FOLDER = Path(os.environ.get("I2PBENCH_EDGEREGNET_REFERENCE") or SAMPLE_DATA / "edgeregnet_reference")
pytestmark = pytest.mark.skipif(
    not (FOLDER / "outputs.npz").is_file(),
    reason=f"sample data not found: {FOLDER} (set I2PBENCH_EDGEREGNET_REFERENCE or I2PBENCH_SAMPLE_DATA)",
)
INTEGER = ("matches",)
FLOATS = (
    "des2d_superpoint", "sa1_points", "sa2_points", "des3d_fp", "enc3d", "enc2d", "gnn3d", "gnn2d", "des3d",
    "des2d", "fov", "sim", "log_assignment", "logsig3d", "logsig2d",
)  # fmt: skip
RELATIVE = 1e-4  # the README's tolerance: another CPU or thread count moves the floats by ~1e-5 of the largest


def relative_error(ours: np.ndarray, ref: np.ndarray) -> float:
    """max |ours - ref| / max |ref|, shapes required equal."""
    assert ours.shape == ref.shape
    return float(np.abs(ours.astype(np.float64) - ref).max() / np.abs(ref).max())


@pytest.fixture(scope="module")
def reference():
    return dict(np.load(FOLDER / "inputs.npz")), dict(np.load(FOLDER / "outputs.npz"))


@pytest.fixture(scope="module")
def official_file(tmp_path_factory):
    """the folder's weights regenerated from the recipe, saved as the authors' checkpoint would be."""
    state, digest = folder_state(FOLDER)
    assert digest == (FOLDER / "weights.sha256").read_text().split()[0]
    path = tmp_path_factory.mktemp("official") / "KITTI.t7"
    torch.save(state, path)
    return path


@pytest.fixture(scope="module")
def imported(official_file, tmp_path_factory):
    """the reference weights through `i2pbench weights import`."""
    out = tmp_path_factory.mktemp("imported") / "W.pt"
    assert main(["weights", "import", "edgeregnet-official", str(official_file), "--out", str(out)]) == 0
    return load_checkpoint(out)


def stages_from(state: dict) -> dict:
    stages = official_stages()
    for kind, module in stages.items():
        module.load_state_dict(state[kind])
        module.eval()
    return stages


@pytest.fixture(scope="module")
def ours(imported, reference):
    torch.set_num_threads(min(2, torch.get_num_threads()))
    return reference_forward(stages_from(imported.state), reference[0])


def test_reference_official_size_holds_the_authors_values():
    shapes = json.loads((FOLDER / "state_dict_shapes.json").read_text())
    stages = official_stages()
    count = sum(v.numel() for m in stages.values() for v in m.state_dict().values())
    assert count == sum(int(np.prod(s)) for s in shapes.values()) == 9_789_922
    assert sum(len(m.state_dict()) for m in stages.values()) == len(shapes) == 374


def test_reference_import_records_where_the_weights_come_from(imported, official_file):
    origin = imported.meta["imported_from"]
    assert origin["file"] == "KITTI.t7" and origin["importer"] == "edgeregnet-official"
    assert origin["sha256"] == __import__("hashlib").sha256(official_file.read_bytes()).hexdigest()
    assert imported.trained_on == "authors' release (KITTI 00-08)"
    assert imported.meta["stages"]["exchanger"]["name"] == "attention-official"


def test_reference_import_round_trips_the_state_dict(imported, official_file):
    state, unknown = importer.split(torch.load(official_file, weights_only=True))
    assert not unknown
    for kind, tensors in state.items():
        assert tensors.keys() == imported.state[kind].keys()
        assert all(torch.equal(tensors[k], imported.state[kind][k]) for k in tensors)


def test_reference_import_refuses_a_file_that_does_not_fit(official_file, tmp_path):
    state = torch.load(official_file, weights_only=True)
    state["gnn.layers.0.mlp.0.weight"] = state["gnn.layers.0.mlp.0.weight"][:, :256]
    del state["kenc3d.encoder3d.12.bias"]
    state["extra.weight"] = torch.zeros(1)
    torch.save(state, tmp_path / "bad.t7")
    with pytest.raises(Exception, match="extra.weight") as err:
        importer.import_official(tmp_path / "bad.t7")
    assert "missing key exchanger.kenc3d.12.bias" in str(err.value)
    assert "layers.0.mlp.0.weight: shape (512, 256), expected (512, 512)" in str(err.value)


@pytest.mark.parametrize("name", FLOATS)
def test_reference_tensor(name, ours, reference):
    assert relative_error(ours[name], reference[1][name]) <= RELATIVE


@pytest.mark.parametrize("name", INTEGER)
def test_reference_integer_outputs(name, ours, reference):
    np.testing.assert_array_equal(ours[name], reference[1][name])


def test_reference_fps_and_balls(reference):
    """our FPS, started at the authors' first draw, draws their indices; our balls are theirs."""
    inputs = reference[0]
    xyz = torch.from_numpy(inputs["xyz"][None, :, :3]).contiguous()
    fps1 = farthest_point_sampling(xyz, len(inputs["fps_sa1"]), int(inputs["fps_sa1"][0]))
    np.testing.assert_array_equal(fps1[0].numpy(), inputs["fps_sa1"])
    centres = xyz[:, fps1[0]].contiguous()
    fps2 = farthest_point_sampling(centres, len(inputs["fps_sa2"]), int(inputs["fps_sa2"][0]))
    np.testing.assert_array_equal(fps2[0].numpy(), inputs["fps_sa2"])
    sa2 = official_stages()["encoder3d"].conf["sa2"]
    inner = centres[:, fps2[0]]
    assert torch.equal(fast_ball_query(centres, inner, sa2["radius"], sa2["nsample"]),
                       ball_query(centres, inner, sa2["radius"], sa2["nsample"]))  # fmt: skip


def test_reference_preprocessing(reference):
    """the 3D branch's normalisation of the frame in metres gives the recorded normalised cloud."""
    inputs = reference[0]
    frame, _, _ = reference_frame(inputs)
    cloud = torch.from_numpy(frame.points)
    assert relative_error(normalize(cloud, cloud).numpy(), inputs["xyz"]) <= 1e-6


def test_reference_losses(ours, reference):
    """the authors' projection of the edge points and their three losses, on our outputs."""
    inputs, outputs = reference
    frame, kp2d, kp3d = reference_frame(inputs)
    K, T = (torch.from_numpy(np.asarray(a, np.float32)) for a in (frame.K, frame.T_gt))
    xy = project(torch.from_numpy(kp3d.xyz), K, T, (1250, 375)).numpy()
    assert relative_error(xy, outputs["xy_projected"]) <= RELATIVE
    assert ((xy == 0).all(1) == (outputs["xy_projected"] == 0).all(1)).all()
    names = {"log_assignment": "log_assignment", "fov": "fov_logits", "z3d": "z3d", "z2d": "z2d"}
    out = {k: torch.from_numpy(ours[name]) for k, name in names.items()}
    terms = official_loss(out, torch.from_numpy(outputs["xy_projected"]), torch.from_numpy(kp2d.uv))
    for ours_name, name in (("fov", "loss_fov"), ("P", "loss_p"), ("sigma", "loss_sigma")):
        assert abs(float(terms[ours_name]) - float(outputs[name])) <= RELATIVE * abs(float(outputs[name]))


def test_reference_wrong_head_layout_fails(official_file, reference, monkeypatch):
    """imported without regrouping the heads, the attention no longer computes the authors' GNN."""
    monkeypatch.setattr(importer, "head_order", lambda dim, heads=4: torch.arange(dim))
    state, _ = importer.split(torch.load(official_file, weights_only=True))
    wrong = reference_forward(stages_from(state), reference[0])
    assert relative_error(wrong["gnn2d"], reference[1]["gnn2d"]) > 100 * RELATIVE
    assert relative_error(wrong["enc2d"], reference[1]["enc2d"]) <= RELATIVE  # before the GNN: unaffected


def test_reference_untied_layer_fails(official_file, reference):
    """a GNN whose 2D side has weights of its own (here: the next layer's) is not the authors' tied GNN."""
    state, _ = importer.split(torch.load(official_file, weights_only=True))
    stages = stages_from(state)
    layers = list(stages["exchanger"].layers)

    class Untied(torch.nn.Module):
        """the first layer with the 2D side's update taken from the second layer's weights."""

        def forward(self, *args):
            return layers[0](*args)[0], layers[1](*args)[1]

    stages["exchanger"].layers = torch.nn.ModuleList([Untied(), *layers[1:]])
    wrong = reference_forward(stages, reference[0])
    assert relative_error(wrong["gnn3d"], reference[1]["gnn3d"]) > 100 * RELATIVE


def test_reference_superpoint_init_takes_magic_leaps_keys(official_file, tmp_path):
    """`train --init-2d superpoint_v1.pth`: Magic Leap's keys are the official encoder2d's own (conv1a..convDb, the
    authors load that file into it: models/superpoint.py:137-138); a file missing one is refused by name."""
    from i2pbench.errors import WeightsError
    from i2pbench.weights.checkpoints import load_init

    official = torch.load(official_file, weights_only=True)
    magic_leap = {k.removeprefix("superpoint."): v for k, v in official.items() if k.startswith("superpoint.")}
    torch.save(magic_leap, tmp_path / "superpoint_v1.pth")
    encoder = official_stages()["encoder2d"]
    origin = load_init(encoder, tmp_path / "superpoint_v1.pth")
    assert origin["file"] == "superpoint_v1.pth" and len(origin["sha256"]) == 64
    assert torch.equal(encoder.convDb.weight, magic_leap["convDb.weight"])
    del magic_leap["convPb.bias"]
    torch.save(magic_leap, tmp_path / "broken.pth")
    with pytest.raises(WeightsError, match="convPb.bias"):
        load_init(encoder, tmp_path / "broken.pth")
