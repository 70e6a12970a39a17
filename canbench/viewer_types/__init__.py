"""The viewer's ROS 2 types: one registry, LOGGERS, from a ROS 2 type name to
the function that turns one decoded message into Rerun archetypes.

Adding a type is three steps:
  1. its CDR struct in canbench/ros2_msgs.py (field for field its .msg file), listed in ALL;
  2. a function `def log_x(ctx: Context, path: str, msg) -> None` in a module here;
  3. `@logger("pkg/msg/Type")` on that function (a new module also gets imported below).

Loggers raise ValueError for contents that contradict themselves (an image shorter
than height * step, a field past point_step): the viewer counts the sample as
malformed and goes on. Frames: Rerun's named coordinate frames are ROS 2 frame
ids, so data carrying header.frame_id sits in the TF tree the tf loggers build
(and in a URDF's links, which Rerun names the same way)."""
from __future__ import annotations

from . import can, diagnostics, geometry, images, markers, points, scalars, sensors  # noqa: F401 - they register their loggers
from .registry import LOGGERS, Context, Logger, logger, require

__all__ = ["LOGGERS", "Context", "Logger", "logger", "require"]
