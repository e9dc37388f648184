"""The shared layer package (i2pbench.layers): the cache keys of the components built on it are those they had before
it existed, and a layer's revision moves the key of every component using it, and of no other."""

import hashlib
import io
import tokenize
from pathlib import Path

import pytest

import i2pbench.layers
from i2pbench import layers
from i2pbench.registry.build import default_registry
from i2pbench.runs.jobs import _described
from i2pbench.runs.store import cache_key
from i2pbench.training.samples import signature

LAYERS = Path(i2pbench.layers.__file__).parent

# cache_key of each stage's description ({name, conf, revision, layers}), computed on main before the shared layers
# moved out of the edgeregnet and corri2p plugins (commit d6c9aec): a run's frame key hashes these with the data,
# weights and protocol, so equal values here mean every cached result of these components is still found. The rows
# on `pointnet2` and `kernels` were recomputed when those went to REVISION 1 (issue 39: FPS rounds its distances as
# the authors' PointNet++ code, which can move a centroid at a near tie), so their cached results are recomputed
STAGE_KEYS = {
    ("corri2p", "cpu-size", "encoder2d", "corri2p-resnet"): "bc548b2ada5fb6378dfc64f3",
    ("corri2p", "cpu-size", "encoder3d", "corri2p-pointnet2"): "336851aad7658795f2a6333a",
    ("corri2p", "cpu-size", "exchanger", "corri2p-exchange"): "aa6ca1c25c89dd4718e1a06e",
    ("corri2p", "cpu-size", "matcher", "corri2p-overlap"): "e43392a3bbdac9c8d5820e78",
    ("corri2p", "paper", "encoder2d", "corri2p-resnet"): "f237d01e1b667ca37fd49c66",
    ("corri2p", "paper", "encoder3d", "corri2p-pointnet2"): "8988777a28f939371d0e9e19",
    ("corri2p", "paper", "exchanger", "corri2p-exchange"): "ec6149c54cef2b783acd77af",
    ("corri2p", "paper", "matcher", "corri2p-overlap"): "9c59066bcf686f3c7a9c5b35",
    ("deepi2p", "cpu-size", "encoder2d", "deepi2p-resnet"): "c60400ebbdc28e859f763791",
    ("deepi2p", "cpu-size", "encoder3d", "deepi2p-pointnet2"): "ec7ba133e04329b6ffdb0f17",
    ("deepi2p", "cpu-size", "exchanger", "deepi2p-fusion"): "f9dfad959f1e11d0a2d8e28c",
    ("deepi2p", "cpu-size", "matcher", "deepi2p-classifier"): "ecf053fdc28eaa75be30e2d6",
    ("deepi2p", "paper", "encoder2d", "deepi2p-resnet"): "4fdb71bae824efd16865032c",
    ("deepi2p", "paper", "encoder3d", "deepi2p-pointnet2"): "eead27a27a712bc842fbf8f4",
    ("deepi2p", "paper", "exchanger", "deepi2p-fusion"): "e8287bcea78844f2221ba76d",
    ("deepi2p", "paper", "matcher", "deepi2p-classifier"): "d883676d9605a01b927827e5",
    ("edgeregnet", "cpu-size", "encoder2d", "superpoint-cnn"): "682c0a262a5dfa992beb6aed",
    ("edgeregnet", "cpu-size", "encoder3d", "pointnet2"): "f7cf1df0ad2ee12829ab3c2d",
    ("edgeregnet", "cpu-size", "exchanger", "attention"): "85299e4f07939b41ef7b6b03",
    ("edgeregnet", "paper", "encoder2d", "superpoint-cnn"): "9854dcedb4774d8aa2dba136",
    ("edgeregnet", "paper", "encoder3d", "pointnet2"): "d38c53fdd3f29f79dd5edd47",
    ("edgeregnet", "paper", "exchanger", "attention"): "bf85caf87e1288833ed01006",
    ("edgeregnet", "official", "encoder3d", "pointnet2-official"): "0d08b5b0bb23073ccb58e085",
    ("edgeregnet", "official", "exchanger", "attention-official"): "6928ab1c79bed4c69d037356",
    ("edgeregnet", "official", "matcher", "match-assignment-official"): "9b77007cf6285f1daea2663f",
}

# each layer module's revision and the fingerprint of its code (comments, blank lines and trailing spaces left out).
# A failure here means a layer's code changed: if its outputs can change for the same inputs, bump the module's
# REVISION (every component using it then gets a new cache key and recomputes); either way record both here.
LAYER_CODE = {
    "attention": (0, "573a14854cd7"),
    "canonical": (0, "0bde0510db44"),
    "cluster_max": (0, "af4852f06a08"),
    "epropnp": (0, "76452d0c92bd"),  # EPro-PnP's Monte-Carlo pose loss (issue 40, VP2P-Match's training)
    "frame_norm": (0, "b360eba841ba"),
    "global_pointnet2": (0, "03daa78cf4e8"),  # BatchedStage, seeded_cloud, deep merge_conf; issue 38's import paths
    "kernels": (1, "2aab15a2d71f"),  # FPS as the authors' PointNet++ (issue 39); grid-pruned FPS, ball query: same
    "kpconv": (0, "afae9f47a5ac"),  # KPConv of CoFiI2P's official size (issue 39)
    "mlp": (0, "1e8fb86b56f9"),
    "nodes": (0, "57e284127b45"),
    "peer_inputs": (2, "48535a034fcc"),  # a loader card's frame taken as it is (crop, T_init axes); issue 38 paths
    "point_pyramid": (0, "89a7e54dc7c8"),  # CoFiI2P's KPConv pyramid (issue 39)
    "pointnet2": (1, "ee6c35457d80"),  # the torch FPS rounds as the compiled one (issue 39); seeded_cloud: same
    "point_voxel": (0, "6454dd9cb5d5"),
    "positions": (0, "bba0b2ef6d56"),  # EdgeRegNet's two pixel normalisations, moved from its exchangers: same outputs
    "resnet": (0, "38d6e5b5dcfe"),
    "sampling": (0, "dd084e30084c"),
    "sparse": (0, "862328a80b46"),
}


def fingerprint(path: Path) -> str:
    text = path.read_text().replace("\r\n", "\n")
    lines = text.split("\n")
    for token in tokenize.generate_tokens(io.StringIO(text).readline):
        if token.type == tokenize.COMMENT:
            row, col = token.start
            lines[row - 1] = lines[row - 1][:col]
    return hashlib.sha256("\n".join(line.rstrip() for line in lines if line.strip()).encode()).hexdigest()[:12]


@pytest.fixture(scope="module")
def registry():
    return default_registry()


def stage(registry, method: str, size: str, kind: str):
    row = registry.method(method).row(size)
    return registry.component(kind, row[kind])(row["confs"].get(kind))


@pytest.mark.parametrize(("method", "size", "kind", "name"), sorted(STAGE_KEYS))
def test_stage_keys_of_components_on_shared_layers_are_unchanged(registry, method, size, kind, name):
    component = stage(registry, method, size, kind)
    assert component.name == name
    assert layers.used_layers(type(component))  # built on the shared layers: the components the move could touch
    assert cache_key(_described(component)) == STAGE_KEYS[method, size, kind, name]


def test_each_layer_module_code_matches_its_recorded_revision():
    modules = {p.stem: p for p in LAYERS.glob("*.py") if p.stem != "__init__"}
    assert set(modules) == set(LAYER_CODE), "a layer module was added or removed: record it in LAYER_CODE"
    changed = []
    for name, path in sorted(modules.items()):
        revision, code = LAYER_CODE[name]
        module = __import__(f"i2pbench.layers.{name}", fromlist=["REVISION"])
        if (module.REVISION, fingerprint(path)) != (revision, code):
            changed.append(f"{name}: REVISION {module.REVISION}, fingerprint {fingerprint(path)!r}")
    assert not changed, "layer code changed; bump REVISION if outputs can change, then record:\n" + "\n".join(changed)


def test_components_use_the_layers_their_code_imports(registry):
    def used(kind, name):
        return layers.used_layers(registry.component(kind, name))

    # through the plugin's own modules and the layers' imports of each other
    assert used("encoder3d", "corri2p-pointnet2") == (
        "canonical",
        "frame_norm",
        "global_pointnet2",
        "kernels",
        "pointnet2",
    )
    assert used("encoder2d", "superpoint-cnn") == ("sampling",)
    assert used("matcher", "deepi2p-classifier") == ("mlp",)
    assert used("matcher", "lightglue") == ()
    assert used("extractor2d", "lsd") == ()  # a classic stage: no layer


def test_a_layer_revision_moves_the_keys_of_the_components_using_it_only(registry, monkeypatch):
    edge = stage(registry, "edgeregnet", "cpu-size", "encoder3d")
    corr = stage(registry, "corri2p", "cpu-size", "encoder3d")
    image = stage(registry, "edgeregnet", "cpu-size", "encoder2d")
    before = [cache_key(_described(c)) for c in (edge, corr, image)]
    stored = [signature(c) for c in (edge, corr, image)]
    monkeypatch.setattr(layers.pointnet2, "REVISION", 2)
    moved = {"kernels": layers.kernels.REVISION, "pointnet2": 2}
    assert _described(corr)["layers"] == moved and _described(edge)["layers"] == moved
    after = [cache_key(_described(c)) for c in (edge, corr, image)]
    assert after[0] != before[0] and after[1] != before[1]  # EdgeRegNet's and CorrI2P's encoders both recompute
    assert after[2] == before[2] and "layers" not in _described(image)  # the image encoder uses no PointNet++ layer
    # the training cache of prepared inputs (the grouping) is refilled too
    assert [signature(c) for c in (edge, corr, image)][:2] != stored[:2]
    assert signature(image) == stored[2]
