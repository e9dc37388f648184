"""Geometry: rigid transforms and pinhole projection (`transforms`), and ground-truth 2D-3D
correspondences (`correspondence`)."""
