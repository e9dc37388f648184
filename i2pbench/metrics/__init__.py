"""What a result is scored by: the pose errors, and the metrics declared once for the store, boards and training.

- `pose`: RTE, RRE (the peers' 'xzy' Euler sum) and the geodesic angle of one estimate, success under a protocol;
- `registry`: the `Metric` declarations, the built-in ones (`BUILTIN`) and the check of a plugin's;
- `installed`: the metrics in force (built-ins, then the installed plugins'), and what is computed from them.
"""
