"""Third-party stages that fault in the ways that used to kill or hang a whole run, for the fault tests.

Each misbehaves on the frames named by its `frame` config ("a" by default, "any" for all) and behaves elsewhere, so
the frames around it show whether the run went on. `rival` is a separate plugin whose `lsd` clashes with a built-in.
"""

import ctypes
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

from i2pbench.api import Extractor2D, Extractor3D, Keypoints2D, Keypoints3D, hookimpl


class _Faulty(Extractor3D):
    default_conf = {"frame": "a", "seconds": 60.0, "markers": ""}  # which frames; how long to hang; where to say so

    def __call__(self, frame):
        if self.conf["frame"] in ("any", frame.frame_id):
            if self.conf["markers"]:  # tells a test which process is in the stage, and that it got there
                Path(self.conf["markers"], f"{frame.frame_id}.{os.getpid()}").touch()
            self.fault()
        return Keypoints3D.from_index(frame, np.arange(3))

    def fault(self):
        raise NotImplementedError


class Exits(_Faulty):
    name = "exit"

    def fault(self):
        sys.exit(3)


class Interrupts(_Faulty):
    name = "interrupt"

    def fault(self):
        raise KeyboardInterrupt


class ClosesGenerator(_Faulty):
    name = "generator-exit"

    def fault(self):
        raise GeneratorExit


class HardExits(_Faulty):
    """Ends its process at once, skipping every handler (as a crash in C would)."""

    name = "hard-exit"

    def fault(self):
        os._exit(3)


class HoldsTheGil(_Faulty):
    """Sleeps inside a C call that keeps the GIL (ctypes.pythonapi calls never release it): no thread runs meanwhile."""

    name = "gil"

    def fault(self):
        ctypes.pythonapi.sleep(int(self.conf["seconds"]))


class PressesCtrlC(_Faulty):
    """Stands for the user pressing Ctrl-C while the stage runs: a real SIGINT to this process."""

    name = "ctrl-c"

    def fault(self):
        signal.raise_signal(signal.SIGINT)
        time.sleep(self.conf["seconds"])  # the handler raises in the main thread, maybe not this one


class Naps(_Faulty):
    """Sleeps the ordinary way (the GIL released), long enough to be interrupted or killed mid-frame."""

    name = "nap"

    def fault(self):
        time.sleep(self.conf["seconds"])


@hookimpl
def register_extractors_3d(register):
    for cls in (Exits, Interrupts, ClosesGenerator, HardExits, HoldsTheGil, PressesCtrlC, Naps):
        register(cls)


class RivalLsd(Extractor2D):
    name = "lsd"  # the classic plugin's

    def __call__(self, frame):
        return Keypoints2D(np.zeros((0, 2), np.float32))


class RivalOnly(Extractor2D):
    name = "rival-only"

    def __call__(self, frame):
        return Keypoints2D(np.zeros((0, 2), np.float32))


class RivalPlugin:
    @hookimpl
    def register_extractors_2d(self, register):
        register(RivalOnly)
        register(RivalLsd)


rival = RivalPlugin()
