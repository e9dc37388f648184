"""The authors' state-dict layout (network.py `CorrI2P`, saved by train.py:277-292 as `model.state_dict()`, or
under `module.` when wrapped in DataParallel) and ours (network.py `CorrI2PNet`): the key mapping, both ways.

- `pc_encoder.{first,second,final}_pointnet.layers.i.{conv,norm}` -> `encoder3d.{first,second,last}.i.{0,1}`;
  `pc_encoder.knnlayer.layers_{before,after}.i.{conv,norm}` -> `encoder3d.knn.{before,after}.i.{0,1}`;
- `img_encoder.backbone.*` -> `encoder2d.*` (torchvision's names); its `fc.*` (ImageNet classes, never used in the
  forward) is dropped;
- `img_{32,16}_attention_conv.*` -> `exchange.image_attention{32,16}.*`; `up_conv{1,2,3}.conv.j.*` ->
  `exchange.up{16,8,4}.blocks.j.*`; `node_{b,a}_attention_pn`, `node_{b,a}_pn`, `per_point_pn` `.layers.i.{conv,
  norm}` -> `exchange.node_{b,a}_attention`, `exchange.node_{b,a}_mlp`, `exchange.per_point` `.i.{0,1}`;
- `{pc,img}_{feature,score}_layer.*` -> `heads.{point,pixel}_{descriptor,score}.*`.
"""

from __future__ import annotations

import re

DROPPED = re.compile(r"img_encoder\.backbone\.fc\.(weight|bias)")
POINTNETS = {
    "pc_encoder.first_pointnet": "encoder3d.first",
    "pc_encoder.second_pointnet": "encoder3d.second",
    "pc_encoder.final_pointnet": "encoder3d.last",
    "pc_encoder.knnlayer.layers_before": "encoder3d.knn.before",
    "pc_encoder.knnlayer.layers_after": "encoder3d.knn.after",
    "node_b_attention_pn": "exchange.node_b_attention",
    "node_b_pn": "exchange.node_b_mlp",
    "node_a_attention_pn": "exchange.node_a_attention",
    "node_a_pn": "exchange.node_a_mlp",
    "per_point_pn": "exchange.per_point",
}
PLAIN = {
    "img_encoder.backbone": "encoder2d",
    "img_32_attention_conv": "exchange.image_attention32",
    "img_16_attention_conv": "exchange.image_attention16",
    "up_conv1.conv": "exchange.up16.blocks",
    "up_conv2.conv": "exchange.up8.blocks",
    "up_conv3.conv": "exchange.up4.blocks",
    "pc_feature_layer": "heads.point_descriptor",
    "pc_score_layer": "heads.point_score",
    "img_feature_layer": "heads.pixel_descriptor",
    "img_score_layer": "heads.pixel_score",
}
LAYER_PARTS = {"conv": "0", "norm": "1"}


def ours(key: str) -> str | None:
    """an authors' key (any `module.` prefix stripped) -> our key; None for a key we drop or do not know."""
    key = key.removeprefix("module.")
    if DROPPED.fullmatch(key):
        return None
    for theirs, mine in POINTNETS.items():
        if match := re.fullmatch(re.escape(theirs) + r"(?:\.layers)?\.(\d+)\.(conv|norm)\.(.+)", key):
            index, part, rest = match.groups()
            return f"{mine}.{index}.{LAYER_PARTS[part]}.{rest}"
    for theirs, mine in PLAIN.items():
        if key.startswith(theirs + "."):
            return mine + key[len(theirs) :]
    return None


def dropped(key: str) -> bool:
    """whether an authors' key is one we leave out on purpose (the unused ImageNet classifier)."""
    return DROPPED.fullmatch(key.removeprefix("module.")) is not None
