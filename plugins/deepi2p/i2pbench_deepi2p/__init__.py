"""DeepI2P (Li & Lee, CVPR 2021): registration by per-point classification, the parts with closed forms.

`labels` (frustum and grid-cell targets), `grid_matches` (grid predictions as Matches for the classic PnP solvers),
`poses` (the pose families searched), `inverse_projection` (the frustum objective), `frustum_solver` (its
multi-start solver, the 2D and 3D variants). Nothing is registered yet: see this plugin's README.
"""
