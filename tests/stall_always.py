"""A 2D extractor that never finishes a frame: it leaves `started` in the working folder, then sleeps until the run
is stopped, so a test can stop a run before any frame finished (test_issue44_faults)."""

import os
import time
from pathlib import Path

from i2pbench_classic.extract2d import CannyExtractor

from i2pbench.api import hookimpl


class StallAlways(CannyExtractor):
    name = "stall-always"

    def __call__(self, frame):
        Path(f"started.{os.getpid()}").write_text(frame.frame_id)
        time.sleep(3600)


class StallAlwaysPlugin:
    @hookimpl
    def register_extractors_2d(self, register):
        register(StallAlways)
