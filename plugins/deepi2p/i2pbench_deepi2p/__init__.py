"""DeepI2P (Li & Lee, CVPR 2021): registration by per-point classification, as an i2pbench method.

The network: `extract` (the grid cells' centres as image keypoints), `image` and `points` (the encoders), `fusion`
(image features attended into the points), `classifier` (frustum and cell classification, the matcher and its
loss). The back-ends: grid + PnP through the classic `epnp-ransac`, and `solver` (inverse camera projection from
the frustum scores). The closed forms under them: `labels` (frustum and grid-cell targets), `grid_matches`, `poses`
(the pose families searched), `inverse_projection` (the frustum objective), `frustum_solver` (its multi-start
solver, the 2D and 3D variants). `configs` and `method` declare the method; `plugin` registers it.
"""
