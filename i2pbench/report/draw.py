"""Pixel-exact drawing of projected points, captions and a distance legend, on plain RGB arrays.

Points are rasterised with numpy rather than a plotting library, so a point lands on exactly the pixel that
`project_points` computes (pixel centres at integer coordinates, OpenCV's convention): the tests compare the drawn
pixels with `geometry.project`. Where points overlap, the nearest one wins (a z-buffer), so a pole in front of a wall
stays visible.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.transforms import in_image, project, transform_points

NEAR_M, FAR_M = 3.0, 50.0  # distance colour scale: warm at NEAR_M and closer, cool at FAR_M and beyond
COOLEST = 28  # turbo below this is near-black violet, invisible on a dark image
CAPTION_PX = 26  # height of one caption line
FONT = cv2.FONT_HERSHEY_SIMPLEX  # Hershey fonts are ASCII only: captions write "deg", not a degree sign


def project_points(K: np.ndarray, T: np.ndarray, xyz: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """(pixels [M x 2], distances [M] in metres, rows [M] of xyz) of the points landing in the image under T.

    The single projection used by every overlay: `geometry.project` then `geometry.in_image`, so what is drawn is
    what the protocol's ground-truth matching and the metrics see.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    uv, front = project(K, T, xyz)
    rows = np.flatnonzero(in_image(uv, front, size))
    distance = np.linalg.norm(transform_points(T, xyz[rows]), axis=1)
    return uv[rows], distance, rows


def pixel_of(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[M x 2] int (column, row) of the pixel whose centre is nearest each point, kept inside the image."""
    w, h = size
    px = np.rint(np.asarray(uv, dtype=np.float64)).astype(np.int64)
    return np.clip(px, 0, [w - 1, h - 1])


def distance_colours(distance: np.ndarray, near: float = NEAR_M, far: float = FAR_M) -> np.ndarray:
    """[M x 3] uint8 RGB on the turbo colour map: near points warm (red), far points cool (blue), as in the paper."""
    warmth = np.clip((far - np.asarray(distance, dtype=np.float64)) / (far - near), 0.0, 1.0)
    values = np.rint(COOLEST + (255 - COOLEST) * warmth).astype(np.uint8).reshape(-1, 1)
    return cv2.applyColorMap(values, cv2.COLORMAP_TURBO).reshape(-1, 3)[:, ::-1].copy()


def _disk(radius: int) -> np.ndarray:
    """[S x 2] pixel offsets of a filled disk (radius 1: the 3 x 3 square)."""
    r = np.arange(-radius, radius + 1)
    dx, dy = np.meshgrid(r, r)
    inside = dx**2 + dy**2 <= radius * radius + radius
    return np.stack([dx[inside], dy[inside]], axis=1)


def draw_points(
    canvas: np.ndarray, uv: np.ndarray, colours: np.ndarray, depth: np.ndarray | None = None, radius: int = 1
) -> np.ndarray:
    """Paint each point as a disk of `radius` pixels into canvas [H x W x 3] (in place); nearer points win overlaps."""
    h, w = canvas.shape[:2]
    colours = np.broadcast_to(np.asarray(colours, dtype=np.uint8), (len(uv), 3))
    depth = np.zeros(len(uv)) if depth is None else np.asarray(depth, dtype=np.float64)
    offsets = _disk(radius)
    px = (pixel_of(uv, (w, h))[None, :, :] + offsets[:, None, :]).reshape(-1, 2)
    point = np.tile(np.arange(len(uv)), len(offsets))
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    px, point = px[inside], point[inside]
    order = np.argsort(depth[point], kind="stable")  # nearest first, so np.unique keeps the nearest per pixel
    _, first = np.unique(px[order, 1] * w + px[order, 0], return_index=True)
    winners = order[first]
    canvas[px[winners, 1], px[winners, 0]] = colours[point[winners]]
    return canvas


def background(image: np.ndarray, brightness: float = 0.85) -> np.ndarray:
    """A grey copy of the RGB image, so coloured points stand out whatever the scene's colours."""
    grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float32) * brightness
    return np.repeat(grey.astype(np.uint8)[:, :, None], 3, axis=2)


def caption(lines: list[str], width: int) -> np.ndarray:
    """A black strip with one line of white text per entry."""
    strip = np.zeros((CAPTION_PX * len(lines), width, 3), np.uint8)
    for i, line in enumerate(lines):
        cv2.putText(strip, line, (8, CAPTION_PX * i + 18), FONT, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return strip


def legend(width: int, near: float = NEAR_M, far: float = FAR_M) -> np.ndarray:
    """The distance colour scale as a strip: a gradient bar labelled with its end distances."""
    strip = caption([""], width)
    bar = np.linspace(near, far, max(width // 3, 2))
    x0 = (width - len(bar)) // 2
    strip[6:20, x0 : x0 + len(bar)] = distance_colours(bar)[None, :, :]
    white = (255, 255, 255)
    cv2.putText(strip, f"near {near:g} m", (x0 - 110, 18), FONT, 0.5, white, 1, cv2.LINE_AA)
    cv2.putText(strip, f"far {far:g} m+", (x0 + len(bar) + 8, 18), FONT, 0.5, white, 1, cv2.LINE_AA)
    return strip


def stack(parts: list[np.ndarray]) -> np.ndarray:
    """Parts of the same width, top to bottom."""
    return np.concatenate(parts, axis=0)
