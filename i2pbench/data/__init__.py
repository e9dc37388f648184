"""Datasets: each yields `SensorFrame`s by id; the protocol turns them into registration problems."""

from .base import Dataset

__all__ = ["Dataset"]
