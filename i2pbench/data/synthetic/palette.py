"""Random but plausible materials: colours and LiDAR reflectances in the ranges real street scenes show.

Reflectance values follow what KITTI's HDL-64E reports: asphalt ~0.1-0.3, lane paint ~0.5-0.8, vegetation ~0.3-0.5,
glass near 0, number plates and traffic signs (retro-reflective) ~0.8-1.
"""

from __future__ import annotations

import numpy as np

from .textures import Material

WALLS = [
    (0.85, 0.8, 0.7),
    (0.75, 0.72, 0.68),
    (0.6, 0.3, 0.22),
    (0.9, 0.88, 0.85),
    (0.8, 0.65, 0.4),
    (0.55, 0.55, 0.58),
    (0.7, 0.75, 0.78),
    (0.45, 0.35, 0.3),
]
CARS = [
    (0.9, 0.9, 0.9),
    (0.1, 0.1, 0.12),
    (0.55, 0.57, 0.6),
    (0.6, 0.08, 0.07),
    (0.1, 0.2, 0.5),
    (0.3, 0.33, 0.35),
    (0.85, 0.85, 0.8),
    (0.15, 0.35, 0.2),
]


class Palette:
    """Collects the scene's materials; every `add_*` returns the material id stored on triangles."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.materials: list[Material] = []

    def add(self, kind: str, **params) -> int:
        params.setdefault("seed", int(self.rng.integers(2**31)))
        self.materials.append(Material(kind, params))
        return len(self.materials) - 1

    def jitter(self, rgb, amount: float = 0.08) -> tuple[float, ...]:
        return tuple(float(c) for c in np.clip(np.asarray(rgb) * self.rng.uniform(1 - amount, 1 + amount, 3), 0, 1))

    def pick(self, options) -> tuple[float, ...]:
        return self.jitter(options[int(self.rng.integers(len(options)))])

    def grey(self, lo: float, hi: float) -> tuple[float, float, float]:
        g = float(self.rng.uniform(lo, hi))
        return self.jitter((g, g, g), 0.04)

    def asphalt(self, lines, **extra) -> int:
        paint = (0.92, 0.92, 0.88) if self.rng.random() < 0.85 else (0.95, 0.8, 0.2)
        r = self.rng
        extra.setdefault("patch", (float(r.uniform(2, 8)), float(r.uniform(1, 4))))
        extra.setdefault("patch_frac", float(r.uniform(0.0, 0.25)))
        extra.setdefault("patch_tone", float(r.choice([0.7, 0.8, 1.2, 1.35])))
        return self.add(
            "asphalt",
            color=self.grey(0.18, 0.35),
            ir=float(self.rng.uniform(0.3, 0.45)),
            paint=self.jitter(paint, 0.04),
            paint_ir=float(self.rng.uniform(0.6, 0.95)),
            lines=lines,
            **extra,
        )

    def paving(self) -> int:
        size = float(self.rng.uniform(0.3, 0.8))
        return self.add(
            "tiles",
            color=self.grey(0.45, 0.7),
            ir=float(self.rng.uniform(0.2, 0.35)),
            tile=(size, size * self.rng.choice([1.0, 0.5])),
            joint=0.02,
            offset=0.0,
            joint_dark=0.7,
        )

    def terrain(self) -> int:
        green = self.rng.random() < 0.6
        rgb = (0.25, 0.38, 0.15) if green else (0.45, 0.4, 0.3)
        return self.add("foliage", color=self.jitter(rgb, 0.15), ir=float(self.rng.uniform(0.3, 0.45)), scale=1.5)

    def foliage(self) -> int:
        rgb = self.jitter((0.16, 0.3, 0.1), 0.25)
        return self.add("foliage", color=rgb, ir=float(self.rng.uniform(0.35, 0.55)), scale=0.5, porosity=0.3)

    def plain(self, rgb, ir: float, noise: float = 0.1) -> int:
        return self.add("plain", color=tuple(rgb), ir=float(ir), noise=noise)

    def facade(self, width: float, height: float) -> int:
        r = self.rng
        wall = self.pick(WALLS)
        floor_h = float(r.uniform(2.8, 3.6))
        spacing = float(r.uniform(1.6, 3.2))
        window = (float(r.uniform(0.6, min(1.6, spacing - 0.4))), float(r.uniform(1.0, floor_h - 1.0)))
        return self.add(
            "facade",
            color=wall,
            ir=float(r.uniform(0.25, 0.5)),
            width=width,
            height=height,
            floor_h=floor_h,
            spacing=spacing,
            window=window,
            sill=float(r.uniform(0.6, floor_h - window[1] - 0.2)),
            margin=float(r.uniform(0.3, 1.5)),
            shop=bool(r.random() < 0.35),
            frame_w=float(r.uniform(0.04, 0.12)),
            frame=self.pick([(0.9, 0.9, 0.9), (0.3, 0.25, 0.2), (0.2, 0.2, 0.2)]),
            frame_ir=float(r.uniform(0.3, 0.6)),
            glass=self.jitter((0.15, 0.18, 0.22), 0.2),
            glass_ir=float(r.uniform(0.0, 0.06)),
            band=self.jitter(np.asarray(wall) * r.uniform(0.5, 1.3), 0.1),
            band_ir=float(r.uniform(0.2, 0.6)),
            band_z=float(floor_h * r.integers(1, 3) - 0.15),
            band_w=float(r.uniform(0.0, 0.4)),
        )

    def car_paint(self) -> tuple[int, tuple[float, ...], float]:
        rgb = self.pick(CARS)
        ir = float(np.clip(0.05 + 0.3 * np.mean(rgb) + self.rng.normal(0, 0.03), 0.02, 0.5))
        return self.plain(rgb, ir, 0.05), rgb, ir

    def cabin(self, body_rgb, body_ir: float, glass_z: tuple[float, float]) -> int:
        return self.add(
            "car_cabin",
            color=tuple(body_rgb),
            ir=body_ir,
            glass_z=glass_z,
            glass=self.jitter((0.08, 0.1, 0.12), 0.2),
            glass_ir=float(self.rng.uniform(0.0, 0.05)),
            pillar_period=float(self.rng.uniform(1.1, 1.6)),
            pillar_w=0.15,
        )

    def sign(self, size: float) -> int:
        r = self.rng
        style = int(r.integers(4))
        field, border = [
            ((0.95, 0.95, 0.95), (0.8, 0.1, 0.1)),
            ((0.1, 0.3, 0.7), (0.95, 0.95, 0.95)),
            ((0.95, 0.8, 0.1), (0.1, 0.1, 0.1)),
            ((0.8, 0.1, 0.1), (0.95, 0.95, 0.95)),
        ][style]
        symbol = (0.1, 0.1, 0.1) if style in (0, 2) else (0.95, 0.95, 0.95)
        return self.add(
            "sign",
            size=size,
            shape=str(r.choice(["circle", "square", "diamond"])),
            symbol=str(r.choice(["bar", "arrow"])),
            field=field,
            border=border,
            symbol_rgb=symbol,
            field_ir=0.95 if field[2] > 0.9 else 0.6,
            border_ir=0.95 if border[2] > 0.9 else 0.5,
            symbol_ir=0.95 if symbol[0] > 0.9 else 0.15,
            back=(0.6, 0.6, 0.6),
        )

    def striped(self, rgb, ir: float, band_rgb, band_ir: float, band_range, band_h: float) -> int:
        return self.add(
            "striped",
            color=tuple(rgb),
            ir=ir,
            band=tuple(band_rgb),
            band_ir=band_ir,
            band_range=band_range,
            band_h=band_h,
        )

    def brick(self) -> int:
        rgb = self.pick([(0.6, 0.3, 0.22), (0.75, 0.7, 0.6), (0.5, 0.5, 0.5)])
        return self.add(
            "tiles",
            color=rgb,
            ir=float(self.rng.uniform(0.25, 0.45)),
            tile=(0.25, 0.075),
            joint=0.012,
            offset=0.5,
            joint_dark=1.5,
        )
