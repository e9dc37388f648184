"""Running combinations over datasets into the per-frame results store.

Layered without import cycles: `jobs` (a prepared combination, cache keys) and `frames` (one frame's record) at the
bottom; `tasks` (what a worker is handed and sends back) and `worker` (the one worker code) above them; `executors`
(the driver with its entry points `run_grid` and `run_job`, and the in-process and process-pool executors) and
`ray_executor` on top. Beside them: `grid` (options, presets and grid files into combinations, `--corruption` into
protocols) and `provenance` (the git commit a result was computed at).
"""
