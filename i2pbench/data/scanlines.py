"""Laser (ring) index of a Velodyne scan stored in scan order, for files that carry no ring field (KITTI .bin).

A KITTI HDL-64E .bin holds the points laser by laser, top laser first. Each laser's points start where the scan was
cut, at azimuth 0 (straight ahead, x axis), and sweep counter-clockwise once round to just below 0 again. Measured on
the 43 real frames in ../shared/data (kitti_odometry, kitti_real): within a laser the azimuth steps back by up to
0.22 rad (sequence 04's scans; under 2e-4 in the others), while at a laser change the scan phase (azimuth measured
counter-clockwise from the cut, in [0, 2 pi)) falls by at least 5.59 rad, from near 2 pi to near 0. So a new ring
starts wherever the phase falls by more than `tol` = 1 rad: 4.6x the largest step back, and the smallest boundary
falls 5.6x as far (a 0.01 rad tolerance cut sequence 04's lasers into 134-627 "rings"); 64 rings on every real
frame. A point measured a hair before the cut (azimuth -1e-5) reads as phase ~2 pi and fakes a one- or two-point
ring; boundaries closer than `min_points` to the previous one are such noise and are dropped.
Limit: a laser with no return at all is merged into its neighbour (there is nothing in the point order to see).
"""

from __future__ import annotations

import numpy as np


def scan_phase(xyz: np.ndarray) -> np.ndarray:
    """[N] azimuth counter-clockwise from the x axis in [0, 2 pi): the order a laser sweeps its points in."""
    az = np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0].astype(np.float64))
    return np.mod(az, 2.0 * np.pi)


def ring_starts(phase: np.ndarray, tol: float = 1.0, min_points: int = 8) -> np.ndarray:
    """Indices where a new laser begins (always including 0)."""
    drops = np.flatnonzero(np.diff(phase) < -tol) + 1
    if drops.size == 0:
        return np.zeros(1, np.int64)
    gap_before = np.diff(np.concatenate(([0], drops)))
    return np.concatenate(([0], drops[gap_before >= min_points])).astype(np.int64)


def recover_rings(xyz: np.ndarray, tol: float = 1.0, min_points: int = 8) -> np.ndarray:
    """[N] int16 ring index (0 = first laser in the file, the top one for KITTI) from [N x 3+] points in scan order."""
    n = int(xyz.shape[0])
    ring = np.zeros(n, np.int16)
    if n < 2:
        return ring
    starts = ring_starts(scan_phase(xyz), tol, min_points)
    ring[starts[1:]] = 1
    return np.cumsum(ring, dtype=np.int16)
