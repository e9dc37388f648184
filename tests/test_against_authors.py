"""benchmarks/against_authors.py's own pieces (its timing needs the authors' checkout and minutes, so it is run by
hand, docs/performance.md): the frame at the authors' sizes keeps the reference set's cloud and canvas and draws
its keypoints inside them; a folder that is not the method's checkout is refused by name; the encoder split runs
the forward on the encoders' recorded outputs and gives the encoders back; and, where a checkout is named by its
environment variable, a tiny CorrI2P / DeepI2P / VP2P-Match run checks both sides against the reference set and times
them (VP2P-Match's only where this interpreter has torchsparse, which its authors' code needs)."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import peer_checkout, sample

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "against_authors.py"
sys.path.insert(0, str(SCRIPT.parent))
import against_authors  # noqa: E402


@pytest.fixture
def recorded():
    rng = np.random.default_rng(0)
    canvas = np.zeros((10, 20), np.uint8)
    canvas[:8, :15] = rng.integers(1, 255, (8, 15))  # the image pasted at (0, 0), black beyond
    xyz = rng.standard_normal((50, 4)).astype(np.float32)
    return {"canvas": canvas, "xyz": xyz, "kp3d": xyz[:4], "kp2d": np.zeros((4, 2), np.int16)}


def test_authors_sizes_draw_keypoints_inside_the_image_and_the_cloud(recorded):
    inputs = against_authors.with_keypoints(recorded, 30)
    uv, kp3d = inputs["kp2d"], inputs["kp3d"]
    assert uv.shape == (30, 2) and uv.dtype == np.int16 and kp3d.shape == (30, 4)
    assert uv[:, 0].min() >= 0 and uv[:, 0].max() <= 14 and uv[:, 1].min() >= 0 and uv[:, 1].max() <= 7
    rows = {tuple(r) for r in recorded["xyz"]}
    assert all(tuple(r) in rows for r in kp3d) and len({tuple(r) for r in kp3d}) == 30  # distinct cloud points
    assert inputs["canvas"] is recorded["canvas"] and inputs["xyz"] is recorded["xyz"]
    assert np.array_equal(against_authors.with_keypoints(recorded, 30)["kp2d"], uv)  # seeded


def test_authors_sizes_zero_keeps_the_recorded_keypoints(recorded):
    assert against_authors.with_keypoints(recorded, 0) is recorded


def test_a_folder_without_their_model_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="no models/cali_glue.py"):
        against_authors.import_authors_edgeregnet(tmp_path)


def test_the_table_holds_every_official_method_with_the_authors_code_at_hand():
    assert set(against_authors.METHODS) == {"edgeregnet", "corri2p", "deepi2p", "vp2p-match", "cofii2p"}


NETWORKS = [
    ("corri2p", "network.py"),
    ("deepi2p", "models/networks_united.py"),
    ("vp2p-match", "models/triplet_network.py"),
    ("cofii2p", "model/network.py"),
]


@pytest.mark.parametrize(("method", "file"), NETWORKS)
def test_a_folder_without_the_methods_network_is_refused(method, file, tmp_path):
    args = against_authors.argparse.Namespace(reference=None, points=0)
    with pytest.raises(SystemExit, match=f"{tmp_path}: no {file}; --checkout must be a"):
        against_authors.METHODS[method](tmp_path, args)


class TwoEncoders(torch.nn.Module):
    """a forward reading two encoders once each, as CorrI2P's and DeepI2P's do; the point encoder gives a dict the
    forward adds to, as DeepI2P's forward adds to its encoder's dict."""

    def __init__(self) -> None:
        super().__init__()
        self.image_encoder = torch.nn.Linear(2, 2, bias=False)
        self.point_encoder = torch.nn.Linear(2, 2, bias=False)
        with torch.no_grad():
            self.image_encoder.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 2.0]]))
            self.point_encoder.weight.copy_(torch.tensor([[0.0, 3.0], [1.0, 0.0]]))

    def forward(self, image, points):
        out = {"p": self.point_encoder(points)}
        out |= {"sum": out["p"] + self.image_encoder(image)}
        return out


def test_the_encoder_split_runs_the_rest_on_the_encoders_outputs_and_gives_them_back():
    net = TwoEncoders()
    image, points = torch.tensor([1.0, 1.0]), torch.tensor([2.0, 5.0])
    stages = against_authors.encoder_split(
        net, ("image_encoder", "point_encoder"), (image,), (points,), (torch.zeros(2), torch.zeros(2))
    )
    assert list(stages) == ["image", "points", "exchange"]
    assert stages["image"]().tolist() == [1.0, 2.0] and stages["points"]().tolist() == [15.0, 2.0]
    for _ in range(2):  # the recorded outputs, not the zeros the forward is handed; the dict is not grown
        out = stages["exchange"]()
        assert out["sum"].tolist() == [16.0, 4.0] and list(out) == ["p", "sum"]
    assert isinstance(net.image_encoder, torch.nn.Linear) and isinstance(net.point_encoder, torch.nn.Linear)
    assert net(torch.zeros(2), torch.zeros(2))["sum"].tolist() == [0.0, 0.0]


def test_vp2p_match_without_torchsparse_is_refused_by_name(tmp_path, monkeypatch):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "triplet_network.py").write_text("raise AssertionError('not to be imported')\n")
    found = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "torchsparse" else found(name, *a)
    )
    args = against_authors.argparse.Namespace(reference=None, points=0)
    with pytest.raises(SystemExit, match=f"needs torchsparse 2.0 .*{sys.executable} cannot import"):
        against_authors.METHODS["vp2p-match"](tmp_path, args)


TINY_RUNS = {  # points drawn, stages timed
    "corri2p": (2048, ["image", "points", "exchange"]),
    "deepi2p": (1024, ["image", "points", "exchange"]),
    "vp2p-match": (1024, ["image", "points", "voxels", "fusion"]),
    "cofii2p": (2048, ["pyramid", "image", "points", "exchange"]),
}


@pytest.mark.parametrize("method", sorted(TINY_RUNS))
def test_a_tiny_run_checks_both_sides_against_the_reference_set_then_times_them(method, tmp_path):
    points, stages = TINY_RUNS[method]
    checkout = str(peer_checkout(method))
    if method == "vp2p-match" and importlib.util.find_spec("torchsparse") is None:
        pytest.skip(f"torchsparse is not importable in {sys.executable}: the authors' VP2P-Match code needs it")
    if method == "cofii2p" and importlib.util.find_spec("einops") is None:
        pytest.skip(f"einops is not importable in {sys.executable}: the authors' CoFiI2P transformer needs it")
    sample("kitti_odometry")  # the timed frame is the reference set's, prepared again at --points
    out = tmp_path / "run.json"
    argv = ["--method", method, "--checkout", checkout, "--points", str(points), "--threads", "1", "--repeat", "1"]
    run = subprocess.run([sys.executable, str(SCRIPT), *argv, "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads(out.read_text())
    assert len(report["check"]) >= 4 and max(report["check"].values()) <= 1e-4
    assert {k.split()[0] for k in report["check"]} == {"authors", "ours"}
    table = report["threads"]["1"]["table"]
    assert list(table) == [*stages, "frame"]
    for name in stages:  # wall and CPU seconds, each side, and their ratio
        row = table[name]
        assert min(*row["authors"], *row["ours"]) > 0
        assert row["ratio"][0] == pytest.approx(row["ours"][0] / row["authors"][0])
