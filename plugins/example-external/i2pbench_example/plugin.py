"""The module the `i2pbench` entry point names: its hooks register this package's components."""

from i2pbench.api import hookimpl

from .curvature import CurvatureExtractor
from .harris import HarrisExtractor


@hookimpl
def register_extractors_2d(register):
    register(HarrisExtractor)


@hookimpl
def register_extractors_3d(register):
    register(CurvatureExtractor)
