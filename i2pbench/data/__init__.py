"""Datasets: each yields `SensorFrame`s by id; the protocol turns them into registration problems. `yaml_input` reads
the YAML a user hands in (split files, grid files, `--conf` values) without aliases."""

from .base import Dataset

__all__ = ["Dataset"]
