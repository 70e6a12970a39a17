"""Poses and frames: tf2_msgs/TFMessage (the TF tree), geometry_msgs' stamped types (poses,
points, pose arrays, twists, accelerations, vectors), nav_msgs/Odometry, nav_msgs/Path, nav2's
particle clouds."""
from __future__ import annotations

import numpy as np
import rerun as rr

from .registry import Context, header_stamp, logger
from .scalars import vector_scalars


@logger("tf2_msgs/msg/TFMessage")
def log_tf(ctx: Context, path: str, msg) -> None:
    """Each transform at tf/<root>/.../<child> (the tree as known when that frame first came),
    between the named frames parent and child."""
    for ts in msg.transforms:
        parent, child = ctx.frame(ts.header.frame_id), ctx.frame(ts.child_frame_id)
        if not parent or not child or parent == child:
            raise ValueError(f"transform without two distinct frames: {parent!r} -> {child!r}")
        ctx.parents[child] = parent
        header_stamp(ts.header.stamp)  # each transform at its own stamp: where data of that moment lines up
        t, q = ts.transform.translation, ts.transform.rotation
        transform = rr.Transform3D(translation=[t.x, t.y, t.z], quaternion=rr.Quaternion(xyzw=[q.x, q.y, q.z, q.w]),
                                   parent_frame=parent, child_frame=child)
        # on the entity of the frame's first transform, however the tree grows later (amcl's map -> odom
        # after odom -> base_link): Rerun takes a child frame from two entities as a data error
        entity = ctx.tf_entities.setdefault(child, ctx.frame_path(child))
        rr.log(entity, transform, rr.TransformAxes3D(0.3), static=ctx.static)


@logger("geometry_msgs/msg/PoseStamped")
def log_pose_stamped(ctx: Context, path: str, msg) -> None:
    ctx.pose(path, msg.pose.position, msg.pose.orientation, msg.header.frame_id)


@logger("geometry_msgs/msg/PoseWithCovarianceStamped")
def log_pose_with_covariance_stamped(ctx: Context, path: str, msg) -> None:
    ctx.pose(path, msg.pose.pose.position, msg.pose.pose.orientation, msg.header.frame_id)


@logger("geometry_msgs/msg/PointStamped")
def log_point_stamped(ctx: Context, path: str, msg) -> None:
    p = msg.point
    ctx.log(path, rr.Points3D([[p.x, p.y, p.z]]), frame=msg.header.frame_id)


def x_axis(q) -> list[float]:
    """Where a quaternion turns the x axis (RViz draws a pose array's poses as arrows along it);
    one that is not of unit length is normalised, a zero one leaves x as it is."""
    n = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w
    s = 2 / n if n else 0.0
    return [1 - s * (q.y * q.y + q.z * q.z), s * (q.x * q.y + q.w * q.z), s * (q.x * q.z - q.w * q.y)]


POSE_ARROW_M = 0.3  # RViz's PoseArray arrow length: a particle cloud of 1 m arrows is a hairball


@logger("geometry_msgs/msg/PoseArray")
def log_pose_array(ctx: Context, path: str, msg) -> None:
    """Each pose an arrow along its x axis; a pose with a NaN or infinite value is left out."""
    pose_arrows(ctx, path, msg.poses, np.full(len(msg.poses), POSE_ARROW_M), msg.header.frame_id)


# nav2_rviz_plugins' ParticleCloud display: a particle's arrow from 2 cm (weight 0) to 30 cm
# (weight 1 and more), in its default colour
PARTICLE_ARROW_M = (0.02, 0.3)
PARTICLE_COLOUR = (255, 25, 0)


@logger("nav2_msgs/msg/ParticleCloud")
def log_particle_cloud(ctx: Context, path: str, msg) -> None:
    """amcl's particles: each an arrow along its pose's x axis, as long as its weight says
    (PARTICLE_ARROW_M); one with a NaN or infinite value is left out."""
    shortest, longest = PARTICLE_ARROW_M
    weights = np.asarray([p.weight for p in msg.particles], dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        lengths = np.clip(weights * (longest - shortest) + shortest, shortest, longest)
        lengths[~np.isfinite(weights)] = np.nan
    pose_arrows(ctx, path, [p.pose for p in msg.particles], lengths, msg.header.frame_id, PARTICLE_COLOUR)


def pose_arrows(ctx: Context, path: str, poses, lengths: np.ndarray, frame: str, colour=None) -> None:
    """Each pose an arrow of its length along its x axis; one with a NaN or infinite value is left out."""
    origins = np.asarray([[p.position.x, p.position.y, p.position.z] for p in poses], dtype=np.float64).reshape(-1, 3)
    vectors = np.asarray([x_axis(p.orientation) for p in poses], dtype=np.float64).reshape(-1, 3) * lengths[:, None]
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.isfinite(origins).all(axis=1) & np.isfinite(vectors).all(axis=1)
    ctx.log(path, rr.Arrows3D(origins=origins[finite], vectors=vectors[finite], colors=colour), frame=frame)


def motion_scalars(ctx: Context, path: str, motion) -> None:
    """A Twist's or an Accel's parts as scalars <path>/linear/{x,y,z} and <path>/angular/{x,y,z}."""
    vector_scalars(ctx, f"{path}/linear", motion.linear)
    vector_scalars(ctx, f"{path}/angular", motion.angular)


def _motion_logger(type_name: str, *fields: str) -> None:
    @logger(type_name)
    def log(ctx: Context, path: str, msg) -> None:
        for name in fields:  # down to the Twist or Accel
            msg = getattr(msg, name)
        motion_scalars(ctx, path, msg)


for _type, _fields in (("TwistStamped", ("twist",)), ("AccelStamped", ("accel",)),
                       ("TwistWithCovarianceStamped", ("twist", "twist")),
                       ("AccelWithCovarianceStamped", ("accel", "accel"))):
    _motion_logger(f"geometry_msgs/msg/{_type}", *_fields)


@logger("geometry_msgs/msg/WrenchStamped")
def log_wrench_stamped(ctx: Context, path: str, msg) -> None:
    vector_scalars(ctx, f"{path}/force", msg.wrench.force)
    vector_scalars(ctx, f"{path}/torque", msg.wrench.torque)


@logger("geometry_msgs/msg/PolygonStamped")
def log_polygon_stamped(ctx: Context, path: str, msg) -> None:
    """A closed line through its points (a robot's footprint, a zone) in its frame."""
    loop = [[p.x, p.y, p.z] for p in msg.polygon.points]
    ctx.log(path, rr.LineStrips3D([loop + loop[:1]] if loop else []), frame=msg.header.frame_id)


@logger("geometry_msgs/msg/Vector3Stamped")
def log_vector3_stamped(ctx: Context, path: str, msg) -> None:
    vector_scalars(ctx, path, msg.vector)


@logger("nav_msgs/msg/Odometry")
def log_odometry(ctx: Context, path: str, msg) -> None:
    ctx.pose(path, msg.pose.pose.position, msg.pose.pose.orientation, msg.header.frame_id)
    motion_scalars(ctx, f"{path}/twist", msg.twist.twist)


@logger("nav_msgs/msg/Path")
def log_path(ctx: Context, path: str, msg) -> None:
    strip = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses]
    ctx.log(path, rr.LineStrips3D([strip]), frame=msg.header.frame_id)
