"""Version of the synthetic generator: bump it whenever the output for a given seed changes, so caches regenerate.

v6 made the same scenes as v5 with pinned numerical kernels (pinned.py), so frames are the same bytes on every
machine; `SCENE_DRAWS` keeps seeding every frame's random draws as v5 did, so v6 frames are v5's scenes (what the
shipped weights were trained on) up to the last bits of the kernels' rounding.
"""

GENERATOR_VERSION = 6
SCENE_DRAWS = 5  # the version word in every frame's seed; move it only to draw new scenes
