"""Version of the synthetic generator: bump it whenever the output for a given seed changes, so caches regenerate."""

GENERATOR_VERSION = 5
