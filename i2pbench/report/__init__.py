"""Reports people look at: projection overlays (`i2pbench viz`) and a self-contained HTML page (`i2pbench report`).

Modules: `draw` (rasterising points onto an image, pixel-exact), `overlay` (pose panels and edge/match panels),
`trace` (one pipeline run keeping every stage's output), `rundir` (a runs directory's records and how to reload its
frames), `curves` (matplotlib figures), `html` (the page).
"""
