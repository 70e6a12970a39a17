"""Text and scalar series: std_msgs/String and the std_msgs numbers, the single-value sensor_msgs,
Imu."""
from __future__ import annotations

import rerun as rr

from ..ros2_msgs import Point
from .registry import Context, logger

ZERO = Point()


@logger("std_msgs/msg/String")
def log_string(ctx: Context, path: str, msg) -> None:
    rr.log(path, rr.TextLog(msg.data))


def _field_logger(type_name: str, field_name: str) -> None:
    @logger(type_name)
    def log(ctx: Context, path: str, msg) -> None:
        ctx.scalar(f"{path}/{field_name}", getattr(msg, field_name))


for _type, _field in (("sensor_msgs/msg/Temperature", "temperature"),
                      ("sensor_msgs/msg/FluidPressure", "fluid_pressure"),
                      ("sensor_msgs/msg/RelativeHumidity", "relative_humidity"),
                      ("sensor_msgs/msg/Illuminance", "illuminance")):
    _field_logger(_type, _field)


def vector_scalars(ctx: Context, path: str, vector) -> None:
    for axis in ("x", "y", "z"):
        ctx.scalar(f"{path}/{axis}", getattr(vector, axis))


NO_ESTIMATE = -1.0  # Imu.msg: element 0 of a covariance -1, that estimate is not given (a raw IMU's orientation)


@logger("sensor_msgs/msg/Imu")
def log_imu(ctx: Context, path: str, msg) -> None:
    """Each estimate the IMU gives; one whose covariance starts with -1 it does not, and is left out
    (Imu.msg: "disregard the associated estimate"; a raw IMU's orientation is all zeros)."""
    if msg.angular_velocity_covariance[0] != NO_ESTIMATE:
        vector_scalars(ctx, f"{path}/angular_velocity", msg.angular_velocity)
    if msg.linear_acceleration_covariance[0] != NO_ESTIMATE:
        vector_scalars(ctx, f"{path}/linear_acceleration", msg.linear_acceleration)
    if msg.orientation_covariance[0] != NO_ESTIMATE:
        ctx.pose(f"{path}/orientation", ZERO, msg.orientation, msg.header.frame_id)


@logger("sensor_msgs/msg/MagneticField")
def log_magnetic_field(ctx: Context, path: str, msg) -> None:
    vector_scalars(ctx, f"{path}/magnetic_field", msg.magnetic_field)


@logger("std_msgs/msg/Float64")
def log_float64(ctx: Context, path: str, msg) -> None:
    ctx.scalar(path, msg.data)  # recording.mcap's decoded signals


def _number_logger(type_name: str) -> None:
    @logger(type_name)
    def log(ctx: Context, path: str, msg) -> None:
        ctx.scalar(path, msg.data)  # a Bool as 0 or 1


for _number in ("Bool", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Float32"):
    _number_logger(f"std_msgs/msg/{_number}")
