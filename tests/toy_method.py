"""A third-party learned method declared through `register_methods` alone, over the toy plugin's components.

The method is toy_plugin's learned `linear` encoder and trainable `regress` matcher between its `grid`/`first`
extractors and `truth` solver, at two sizes of the encoder. It implements no other hook: its presets, variant
labels and shipped weights come from the declaration.
"""

from pathlib import Path

from i2pbench.api import Method, MethodPreset, Row, Size, hookimpl

STAGES = {"extractor2d": "grid", "extractor3d": "first", "encoder2d": "linear", "matcher": "regress", "solver": "truth"}
REFERENCE = Size("reference", {"encoder2d": {"dim": 4}}, variant="", description="the encoder's own width")
TINY = Size("tiny", {"encoder2d": {"dim": 2}}, description="half the width")
PRESETS = (
    MethodPreset("toy-tiny", (Row("tiny"),), "the toy method at its tiny size"),
    MethodPreset(
        "toy-sizes",
        (Row("reference"), Row("tiny"), Row("tiny", {"matcher": "truth"})),
        "both sizes, and the tiny row with ground-truth matches",
    ),
)


def method(weights: tuple[Path, ...] = ()) -> Method:
    importers = {"toy-release": "toy_method:import_release"}
    return Method(
        "toy", STAGES, (REFERENCE, TINY), PRESETS, weights, "a linear encoder trained by regression", importers
    )


def import_release(path: Path):
    """another code base's file: a JSON {"w": [[...] x 2] x 2, "b": [...] x 2}, our encoder at its tiny size."""
    import json

    import torch

    from i2pbench.weights.checkpoints import ImportedWeights

    data = json.loads(path.read_text())
    state = {"encoder2d": {"layer.weight": torch.tensor(data["w"]), "layer.bias": torch.tensor(data["b"])}}
    return ImportedWeights("tiny", state, {"release": "a toy release"}, {"format": "json"})


class ToyMethodPlugin:
    """The plugin: `register_methods` only. `weights` are the checkpoints it ships."""

    __name__ = "toy-method"

    def __init__(self, weights: tuple[Path, ...] = ()) -> None:
        self.weights = weights

    @hookimpl
    def register_methods(self, register):
        register(method(self.weights))
