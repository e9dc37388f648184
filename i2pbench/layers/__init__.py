"""Network building blocks that more than one method's plugin uses (as mmdetection3d's `models/layers`).

- `pointnet2`: PointNet++ grouping (FPS, ball query, 3-NN; compiled CPU kernels in `kernels`) and blocks (shared
  MLP, set abstraction, interpolation), the cloud normalisation (`canonical`: the yaw-canonical frame);
- `global_pointnet2`: a two-level PointNet++ encoder with the cloud's global feature (CorrI2P, DeepI2P);
- `sampling`: SuperPoint-style bilinear descriptor sampling, per-image normalisation of a padded batch;
- `resnet`: residual blocks with GroupNorm, the coarse-cell mask of a padded batch (CorrI2P, DeepI2P);
- `frame_norm`, `mlp`: per-keypoint MLPs normalised over each frame's keypoints, or by LayerNorm;
- `attention`, `nodes`: the key mask of padded attention; node pooling and per-frame means;
- `positions`: pixels centred and scaled for positional encoders (EdgeRegNet's and its authors' exchangers);
- `kpconv`: rigid kernel point convolution on fixed-size neighbour lists with a shadow row, and a seeded kernel
  disposition (CoFiI2P's KPConv-FPN);
- `sparse`, `point_voxel`: sparse 3D convolution in plain torch computing torchsparse 2.0's function, and SPVCNN's
  point <-> voxel conversions (VP2P-Match);
- `point_pyramid`: a KPConv point pyramid of random halvings and kNN-128 neighbours, as CoFiI2P's data preparation
  builds it;
- `epropnp`: EPro-PnP's Monte-Carlo pose loss (LM solver, AMIS proposals) for 6-DoF poses (VP2P-Match's training);
- `peer_inputs`: the authors' KITTI inputs for the official sizes of CorrI2P, DeepI2P and VP2P-Match (image crop, cells
  as pixels, 0.1 m voxels with normals, seeded draws and node sampling, the extractors and the matchers' tensors),
  from the dataset's frame or taken as they are from a frame their own protocol card built (`loader_cards`).

Plugins import these and `i2pbench.api`, never each other (tests/test_plugin_imports.py). A shared layer is a
dependency a component's own `revision` cannot see, so each module here declares a `REVISION` of its own, to bump
when its outputs change for the same inputs: the cache key of every component whose code imports the module (its
class's modules and what they import, followed through the component's package and this one) then carries
`{"layers": {module: revision}}` and its cached results are recomputed. Revisions at 0 add nothing, as a component's
`revision` 0 does, so keys made before this package existed still match. tests/test_layers.py keeps a fingerprint
of each module's code next to its revision, so an edit that changes the code fails there until its author either
bumps the revision or records that outputs are unchanged.
"""

from __future__ import annotations

import ast
import functools
import importlib.machinery
import importlib.util
import sys

PACKAGE = __name__


def revisions(component: type | object) -> dict[str, int]:
    """the nonzero `REVISION` of each layer module a component (or its class) uses: what its cache key carries."""
    cls = component if isinstance(component, type) else type(component)
    return {name: revision for name in used_layers(cls) if (revision := _revision(name))}


def used_layers(cls: type) -> tuple[str, ...]:
    """the layer modules (short names) a component class's code imports, directly or through its own package."""
    return _used_layers(cls)


@functools.cache
def _used_layers(cls: type) -> tuple[str, ...]:
    package = _package(cls.__module__)
    todo = [c.__module__ for c in cls.__mro__ if _followed(c.__module__, package)]
    seen: set[str] = set()
    while todo:
        module = todo.pop()
        if module not in seen:
            seen.add(module)
            todo += [m for m in _imports(module) if _followed(m, package) and _is_module(m)]
    return tuple(sorted(m.removeprefix(PACKAGE + ".") for m in seen if m.startswith(PACKAGE + ".")))


def _package(module: str) -> str:
    return module.split(".")[0]


def _followed(module: str, package: str) -> bool:
    """a component's own package is followed (not the core outside this package, nor third-party code)."""
    return module.startswith(PACKAGE + ".") or (_package(module) == package and package != "i2pbench")


def _revision(name: str) -> int:
    module = sys.modules.get(f"{PACKAGE}.{name}") or importlib.import_module(f"{PACKAGE}.{name}")
    return int(getattr(module, "REVISION", 0))


@functools.cache
def _imports(module: str) -> tuple[str, ...]:
    """the absolute names `module`'s source imports (`from X import y`: X and X.y, y perhaps no module)."""
    spec = _spec(module)
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return ()
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    base = module if spec.submodule_search_locations else module.rpartition(".")[0]
    found: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            parent = _absolute(node, base)
            found += [parent, *(f"{parent}.{alias.name}" for alias in node.names)]
    return tuple(found)


def _absolute(node: ast.ImportFrom, base: str) -> str:
    if not node.level:
        return node.module or ""
    parts = base.split(".")
    parent = ".".join(parts[: len(parts) - node.level + 1])
    return f"{parent}.{node.module}" if node.module else parent


def _is_module(name: str) -> bool:
    return name in sys.modules or _spec(name) is not None


def _spec(name: str) -> importlib.machinery.ModuleSpec | None:
    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):  # `from pkg import function`: pkg.function is no module; `__main__` has none
        return None
