"""Procedural surface textures: each returns the visible albedo AND the LiDAR (905 nm) reflectance from the same masks.

Because paint, windows, tiles and signs are evaluated once and feed both the camera's albedo and the LiDAR's
reflectance, a reflectance edge in the scan lies exactly on the painted edge in the image, as on real streets.
The two contrasts are set independently (vegetation is dark in the image but bright to the LiDAR, lane paint and
signs are retro-reflective), because a matcher must learn which image edges have a LiDAR counterpart.
Texture coordinates (u, v) are metres in the surface's frame (see mesh.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

Texture = Callable[[np.ndarray, np.ndarray, dict[str, Any]], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Material:
    """A texture kind and its parameters (colours as RGB in [0, 1], reflectances in [0, 1])."""

    kind: str
    params: dict[str, Any] = field(default_factory=dict)


_CX, _CY, _CS, _MIX = np.uint32(0x8DA6B343), np.uint32(0xD8163841), 0xCB1AB31F, np.uint32(0x5BD1E995)


def _cells(x: np.ndarray) -> np.ndarray:
    """Lattice cell index as uint32 (negative cells wrap, which is fine for hashing)."""
    return np.floor(x).astype(np.int64).astype(np.uint32)


def _finish(h: np.ndarray) -> np.ndarray:
    """Avalanche a uint32 hash (modified in place) into a float in [0, 1)."""
    h ^= h >> np.uint32(13)
    h *= _MIX
    h ^= h >> np.uint32(15)
    return h * (1.0 / 2.0**32)


def _hash(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Integer lattice hash in [0, 1): deterministic across platforms (pure uint32 arithmetic)."""
    return _finish(_cells(ix) * _CX ^ _cells(iy) * _CY ^ np.uint32((seed * _CS) & 0xFFFFFFFF))


def value_noise(u: np.ndarray, v: np.ndarray, scale: float, seed: int) -> np.ndarray:
    """Smooth noise in [0, 1) with features about `scale` metres wide."""
    x, y = u / scale, v / scale
    fx, fy = x - np.floor(x), y - np.floor(y)
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    hx, hy = _cells(x) * _CX, _cells(y) * _CY ^ np.uint32((seed * _CS) & 0xFFFFFFFF)
    hx1, hy1 = hx + _CX, _cells(y + 1) * _CY ^ np.uint32((seed * _CS) & 0xFFFFFFFF)
    a, b = _finish(hx ^ hy), _finish(hx1 ^ hy)
    c, d = _finish(hx ^ hy1), _finish(hx1 ^ hy1)
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


def fbm(u: np.ndarray, v: np.ndarray, scale: float, seed: int, octaves: int = 3) -> np.ndarray:
    """Sum of noise octaves, normalised to [0, 1)."""
    total, weight, norm = np.zeros_like(u, dtype=np.float64), 1.0, 0.0
    for k in range(octaves):
        total += weight * value_noise(u, v, scale / 2**k, seed + 101 * k)
        norm += weight
        weight *= 0.5
    return total / norm


def _mix(mask: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-point choice: b where mask, else a (colours [N x 3] or scalars [N])."""
    m = mask[:, None] if np.ndim(a) == 2 or np.ndim(b) == 2 else mask
    return np.where(m, b, a)


def _noisy(u, v, p, amount: float = 0.25, scale: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    n = fbm(u, v, scale, p["seed"]) - 0.5
    rgb = np.asarray(p["color"])[None] * (1 + amount * n)[:, None]
    ir = np.full(u.shape, p["ir"]) * (1 + 0.5 * amount * n)
    return rgb, ir


def plain(u, v, p):
    """Uniform paint with faint mottling (car bodies, metal, concrete)."""
    return _noisy(u, v, p, amount=p.get("noise", 0.1))


def asphalt(u, v, p):
    """Road surface (u along the road, v lateral) with painted lane lines and optional zebra crossing."""
    rgb, ir = _noisy(u, v, p, amount=0.35, scale=2.0)
    fine = value_noise(u, v, 0.12, p["seed"] + 7) - 0.5
    grain = value_noise(u, v, 0.04, p["seed"] + 8) - 0.5  # aggregate grain: texture edges with no LiDAR edge
    rgb *= (1 + 0.15 * fine + 0.35 * grain)[:, None]
    # Repaired patches and stains: sharp-edged tone changes, as common on real roads, weak in reflectance.
    patch = np.floor(u / p["patch"][0]) * 7 + np.floor(v / p["patch"][1])
    patched = _hash(patch, np.floor(v / p["patch"][1]), p["seed"] + 9) < p["patch_frac"]
    tone = np.where(patched, p["patch_tone"], 1.0)
    rgb *= tone[:, None]
    ir = ir * np.where(patched, 1 + 0.3 * (p["patch_tone"] - 1), 1.0)
    paint = np.zeros(u.shape, bool)
    for offset, width, dash, gap in p.get("lines", ()):
        across = np.abs(v - offset) < width / 2
        along = np.ones_like(across) if gap <= 0 else np.mod(u, dash + gap) < dash
        paint |= across & along
    for s0, s1 in p.get("no_lines", ()):
        paint &= ~((u > s0) & (u < s1))
    for s0, s1, t0, t1 in p.get("zebras", ()):
        paint |= (u > s0) & (u < s1) & (v > t0) & (v < t1) & (np.mod(v - t0, 1.0) < 0.5)
    wear = value_noise(u, v, 0.3, p["seed"] + 3) > 0.12
    paint &= wear
    return _mix(paint, rgb, np.asarray(p["paint"])[None]), _mix(paint, ir, np.full(u.shape, p["paint_ir"]))


def tiles(u, v, p):
    """Paving slabs or brick courses: joints are thin dark lines; alternate rows may be offset (bricks)."""
    rgb, ir = _noisy(u, v, p, amount=0.2, scale=3.0)
    tw, th = p["tile"]
    row = np.floor(v / th)
    shift = np.where(np.mod(row, 2) == 1, p.get("offset", 0.0) * tw, 0.0)
    joint = (np.mod(u + shift, tw) < p["joint"]) | (np.mod(v, th) < p["joint"])
    return _mix(joint, rgb, rgb * p.get("joint_dark", 0.6)), _mix(joint, ir, ir * 0.8)


def facade(u, v, p):
    """Building wall with a window grid per floor, window frames, an optional shop floor and a cornice band."""
    rgb, ir = _noisy(u, v, p, amount=0.2, scale=2.5)
    fh, sp, (ww, wh), sill, margin = p["floor_h"], p["spacing"], p["window"], p["sill"], p["margin"]
    floor, fv = np.floor(v / fh), np.mod(v, fh)
    x = u - margin
    col, fu = np.floor(x / sp), np.mod(x, sp)
    cols = max(int((p["width"] - 2 * margin) // sp), 0)
    inside = (col >= 0) & (col < cols) & (floor >= 0) & (v < p["height"] - 0.8)
    ww_f = np.where((floor == 0) & p["shop"], sp - 0.3, ww)
    wh_f = np.where((floor == 0) & p["shop"], fh - 0.9, wh)
    sill_f = np.where((floor == 0) & p["shop"], 0.5, sill)
    du, dv = np.abs(fu - sp / 2), fv - sill_f
    frame = inside & (du < ww_f / 2) & (dv > 0) & (dv < wh_f)
    border = p["frame_w"]
    glass = frame & (du < ww_f / 2 - border) & (dv > border) & (dv < wh_f - border)
    lit = _hash(col, floor, p["seed"] + 5)
    glass_rgb = np.asarray(p["glass"])[None] * (0.6 + 0.9 * lit)[:, None]
    band = np.abs(v - p["band_z"]) < p["band_w"] / 2
    rgb = _mix(band, rgb, np.asarray(p["band"])[None])
    ir = _mix(band, ir, np.full(u.shape, p["band_ir"]))
    rgb = _mix(frame, rgb, np.asarray(p["frame"])[None])
    ir = _mix(frame, ir, np.full(u.shape, p["frame_ir"]))
    return _mix(glass, rgb, glass_rgb), _mix(glass, ir, np.full(u.shape, p["glass_ir"]))


def car_cabin(u, v, p):
    """Car greenhouse: a band of dark glass between body-coloured pillars (u around the cabin, v world height)."""
    rgb, ir = _noisy(u, v, p, amount=0.08)
    low, high = p["glass_z"]
    pillar = np.mod(u, p["pillar_period"]) < p["pillar_w"]
    glass = (v > low) & (v < high) & ~pillar
    return _mix(glass, rgb, np.asarray(p["glass"])[None]), _mix(glass, ir, np.full(u.shape, p["glass_ir"]))


def _symbol(du: np.ndarray, dv: np.ndarray, r: float, kind: str) -> np.ndarray:
    """A horizontal bar (no entry) or an upward arrow, centred on the sign."""
    if kind == "bar":
        return (np.abs(dv) < 0.12 * r) & (np.abs(du) < 0.5 * r)
    shaft = (np.abs(du) < 0.12 * r) & (dv > -0.5 * r) & (dv < 0.2 * r)
    head = (dv >= 0.2 * r) & (dv < 0.6 * r) & (np.abs(du) < 1.2 * (0.6 * r - dv))
    return shaft | head


def sign(u, v, p):
    """Retro-reflective traffic sign face: a painted border/ring, a field and a bar or arrow symbol."""
    cu, cv, r = p["size"] / 2, p["size"] / 2, p["size"] / 2
    du, dv = u - cu, v - cv
    if p["shape"] == "circle":
        d = np.hypot(du, dv) / r
    elif p["shape"] == "diamond":
        d = (np.abs(du) + np.abs(dv)) / r
    else:
        d = np.maximum(np.abs(du), np.abs(dv)) / r
    border = (d > 0.72) & (d <= 1.0)
    symbol = _symbol(du, dv, r, p["symbol"])
    rgb = np.repeat(np.asarray(p["field"], dtype=np.float64)[None], len(u), 0)
    ir = np.full(u.shape, p["field_ir"])
    rgb, ir = _mix(border, rgb, np.asarray(p["border"])[None]), _mix(border, ir, np.full(u.shape, p["border_ir"]))
    symbol &= d < 0.72
    rgb, ir = _mix(symbol, rgb, np.asarray(p["symbol_rgb"])[None]), _mix(symbol, ir, np.full(u.shape, p["symbol_ir"]))
    outside = d > 1.0
    return _mix(outside, rgb, np.asarray(p["back"])[None]), _mix(outside, ir, np.full(u.shape, 0.3))


def striped(u, v, p):
    """Alternating bands along v (reflective pole bands, bollards, barrier boards)."""
    rgb, ir = _noisy(u, v, p, amount=0.1)
    z0, z1 = p["band_range"]
    band = (v > z0) & (v < z1) & (np.mod(v - z0, 2 * p["band_h"]) < p["band_h"])
    return _mix(band, rgb, np.asarray(p["band"])[None]), _mix(band, ir, np.full(u.shape, p["band_ir"]))


def foliage(u, v, p):
    """Leaves and grass: high-frequency dark green in the image, bright and speckled to the LiDAR (near infrared)."""
    rgb, ir = _noisy(u, v, p, amount=0.6, scale=p.get("scale", 0.6))
    speck = value_noise(u, v, 0.15, p["seed"] + 11) - 0.5
    leaves = value_noise(u, v, 0.05, p["seed"] + 13) - 0.5  # leaf-sized light/shadow clutter, as in real foliage
    rgb *= (1 + 0.5 * speck + 1.2 * leaves)[:, None]
    return rgb, ir * (1 + 0.3 * speck)


TEXTURES: dict[str, Texture] = {
    "plain": plain,
    "asphalt": asphalt,
    "tiles": tiles,
    "facade": facade,
    "car_cabin": car_cabin,
    "sign": sign,
    "striped": striped,
    "foliage": foliage,
}


def evaluate(material: Material, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Albedo [N x 3] and reflectance [N], both clipped to [0, 1]."""
    rgb, ir = TEXTURES[material.kind](u, v, material.params)
    return np.clip(rgb, 0.0, 1.0), np.clip(ir, 0.0, 1.0)
