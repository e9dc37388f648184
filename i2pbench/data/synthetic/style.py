"""Generator styles: knobs that move the synthetic frames' statistics (image tone and texture, street clutter, LiDAR
reflectance floor) without touching the default output.

`Style()` is the default generator: every knob at its default value is a no-op and draws no random number, so the
default frames (and every cache of them) stay byte for byte what they were. Randomness a style needs comes from its
own generator (`style_rng`), seeded by the frame's seed words and the style's name, never from the frame's.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, fields

import numpy as np

from ...errors import DataError


@dataclass(frozen=True)
class Style:
    """How the streets and sensors look. The default look is brighter and flatter than KITTI's, with fewer depth
    edges and fewer zero reflectances (docs/diagnose.md, "Measured: synthetic against real KITTI"); a style closes
    such gaps for training while the default dataset stays as published."""

    name: str = "default"
    exposure: float = 0.9  # auto-exposure maps the frame's 98th-percentile luminance to this (above 1 clips more)
    mean_grey: float | None = None  # when set, expose so the image's mean level (0-1) reads this (metering)
    gamma: float = 1 / 2.2  # tone curve exponent after exposure: larger is darker and more contrasted
    blur: float = 0.6  # pixels: sigma of the optics' Gaussian blur (lower is sharper)
    ambient: float = 1.0  # scale of the sky (ambient) light: lower gives darker shadows
    detail: float = 0.0  # amplitude of fine surface texture the camera sees and the LiDAR does not (0: none)
    detail_scale: float = 0.3  # metres: the largest feature of that texture (4 octaves, down to 1/8 of it)
    props: float = 1.0  # street clutter density: 2 adds the default's pavement clutter, poles and trees again
    foliage_depth: float = 1.0  # scale of how far LiDAR beams reach into foliage (scattered returns, depth edges)
    reflectance_offset: float = 0.0  # subtracted from every return's reflectance before the floor at 0
    reflectance_floor: float = 0.0  # returns weaker than this (after the offset) read 0, as KITTI's weak ones do

    @property
    def is_default(self) -> bool:
        return self == DEFAULT

    def knobs(self) -> dict[str, float | None]:
        """Every knob but the name (what a cached sequence records, so a refitted style regenerates its caches)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "name"}


DEFAULT = Style()

# kitti: fitted to `i2pbench domain-gap` against real KITTI (docs/diagnose.md, "Measured: the kitti style against
# real KITTI (after)"), round values, one knob per gap:
# - mean_grey 0.35, gamma 1: KITTI's camera meters the average (grey mean 90 of 255 on every frame, spread 2) with a
#   near-linear, hard-clipping response: dark shadows and white skies (grey std 80 against the default's 46);
# - ambient 0.4: deeper shadows; blur 0.4 and detail 0.5 at 0.1 m: sharper optics and surface grain for KITTI's
#   gradient energy (gradient q90 150, 10% strong-gradient pixels, against 68 and 4%);
# - props 2 and foliage_depth 5: twice the street clutter and beams reaching metres into foliage, for KITTI's depth
#   edges (3,800 a scan against 1,400; most of them in vegetation on sequence 04);
# - reflectance_offset 0.03 and floor 0.08: 19% of KITTI's returns read exactly 0 (default: 7%).
STYLES: dict[str, Style] = {
    "default": DEFAULT,
    "kitti": Style(
        name="kitti",
        mean_grey=0.35,
        gamma=1.0,
        blur=0.4,
        ambient=0.4,
        detail=0.5,
        detail_scale=0.1,
        props=2.0,
        foliage_depth=5.0,
        reflectance_offset=0.03,
        reflectance_floor=0.08,
    ),
}


def get_style(name: object) -> Style:
    """The style called `name`; a DataError naming it and the known styles otherwise."""
    if not isinstance(name, str) or name not in STYLES:
        raise DataError(f"synthetic dataset: unknown style {name!r}; choose one of {list(STYLES)}")
    return STYLES[name]


def style_rng(style: Style, *words: int) -> np.random.Generator:
    """The style's own generator for one frame: seeded by the frame's seed words and the style's name."""
    return np.random.default_rng([*(int(w) for w in words), zlib.crc32(style.name.encode())])
