"""The conformance kit for plugin authors: run `check_component(MyStage)` (or `assert_conforms` in a test).

    from i2pbench.testing import assert_conforms, check_component
    report = check_component(MyExtractor, conf={"max_keypoints": 500})
    print(report)            # the problems found, each naming its check, and the latency measured
    assert_conforms(MyExtractor)

Sample frames need no dataset: `synthetic_frame(seed)` builds a small complete registration problem;
`kitti_frame(root, frame_id)` loads a real one. `registered_components(plugin)` lists what a plugin registers.
"""

from .frames import kitti_frame, synthetic_frame
from .kit import assert_conforms, check_component, check_declaration
from .plugin import registered_components
from .report import ConformanceReport, Problem

__all__ = [
    "ConformanceReport",
    "Problem",
    "assert_conforms",
    "check_component",
    "check_declaration",
    "kitti_frame",
    "registered_components",
    "synthetic_frame",
]
