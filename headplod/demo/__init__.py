"""The terrain demo viewer: head-coupled perceptual level of detail, live (``headplod demo``).

Modules
-------
loop
    :class:`DemoLoop`, the windowless core shared by the window and the
    headless run; the pose sources (:class:`TrackerPoses`,
    :class:`MousePoses`, :class:`DropoutPoses`) and the failure handling
    (:class:`PoseHold`).
poses
    ``make_poses``: the pose source the command's options ask for.
viewpoints
    The paper's three test views as named model matrices.
hud
    The heads-up display, composed with OpenCV.
keys
    The window's keys (``KEYMAP``), the actions and the key help made from it.
window
    The moderngl-window app (moderngl-window is imported only when a window
    opens).
cli
    ``add_demo_arguments``, ``run_demo`` and the headless run.
"""
from .keys import DEMO_MODES
from .loop import SACCADE_DEG_S, SCENARIOS, VIEW_MODES, DemoLoop, DropoutPoses, FrameResult, MousePoses, Pose, PoseHold, PoseSource, TrackerPoses
from .viewpoints import VIEWPOINTS, Viewpoint, place

__all__ = ["DemoLoop", "FrameResult", "Pose", "PoseSource", "TrackerPoses", "MousePoses", "DropoutPoses",
           "PoseHold", "DEMO_MODES", "SCENARIOS", "VIEW_MODES", "SACCADE_DEG_S", "VIEWPOINTS", "Viewpoint",
           "place"]
