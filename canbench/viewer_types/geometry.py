"""Poses and frames: tf2_msgs/TFMessage (the TF tree), geometry_msgs/PoseStamped,
nav_msgs/Odometry, nav_msgs/Path."""
from __future__ import annotations

import rerun as rr

from .registry import Context, header_stamp, logger
from .scalars import vector_scalars


@logger("tf2_msgs/msg/TFMessage")
def log_tf(ctx: Context, path: str, msg) -> None:
    """Each transform at tf/<root>/.../<child>, between the named frames parent and child."""
    for ts in msg.transforms:
        parent, child = ctx.frame(ts.header.frame_id), ctx.frame(ts.child_frame_id)
        if not parent or not child or parent == child:
            raise ValueError(f"transform without two distinct frames: {parent!r} -> {child!r}")
        ctx.parents[child] = parent
        header_stamp(ts.header.stamp)  # each transform at its own stamp: where data of that moment lines up
        t, q = ts.transform.translation, ts.transform.rotation
        transform = rr.Transform3D(translation=[t.x, t.y, t.z], quaternion=rr.Quaternion(xyzw=[q.x, q.y, q.z, q.w]),
                                   parent_frame=parent, child_frame=child)
        rr.log(ctx.frame_path(child), transform, rr.TransformAxes3D(0.3), static=ctx.static)


@logger("geometry_msgs/msg/PoseStamped")
def log_pose_stamped(ctx: Context, path: str, msg) -> None:
    ctx.pose(path, msg.pose.position, msg.pose.orientation, msg.header.frame_id)


@logger("nav_msgs/msg/Odometry")
def log_odometry(ctx: Context, path: str, msg) -> None:
    ctx.pose(path, msg.pose.pose.position, msg.pose.pose.orientation, msg.header.frame_id)
    vector_scalars(ctx, f"{path}/twist/linear", msg.twist.twist.linear)
    vector_scalars(ctx, f"{path}/twist/angular", msg.twist.twist.angular)


@logger("nav_msgs/msg/Path")
def log_path(ctx: Context, path: str, msg) -> None:
    strip = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses]
    ctx.log(path, rr.LineStrips3D([strip]), frame=msg.header.frame_id)
