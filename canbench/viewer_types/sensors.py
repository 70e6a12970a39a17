"""A vehicle's other sensors: sensor_msgs/NavSatFix (a point on Rerun's map), Range (an
ultrasonic or infrared distance), BatteryState, JointState (scalar series)."""
from __future__ import annotations

import math

import numpy as np
import rerun as rr

from .registry import Context, logger, require

STATUS_FIX = 0  # NavSatStatus: NO_FIX -1 and UNKNOWN -2 carry no position


@logger("sensor_msgs/msg/NavSatFix")
def log_nav_sat_fix(ctx: Context, path: str, msg) -> None:
    """A fix as a GeoPoint (Rerun's map view), its altitude and status as scalars; a message
    without a fix (or NaN coordinates, as receivers send them then) places no point."""
    fixed = msg.status.status >= STATUS_FIX and math.isfinite(msg.latitude) and math.isfinite(msg.longitude)
    require(not fixed or -90 <= msg.latitude <= 90, f"a fix at latitude {msg.latitude}: beyond a pole")
    require(not fixed or -180 <= msg.longitude <= 360, f"a fix at longitude {msg.longitude}: beyond -180..360")
    ctx.scalar(f"{path}/status", msg.status.status)
    if not fixed:
        return
    longitude = (msg.longitude + 180) % 360 - 180  # east of 180 as some receivers give it (0..360)
    rr.log(path, rr.GeoPoints(lat_lon=[[msg.latitude, longitude]]), static=ctx.static)
    if math.isfinite(msg.altitude):
        ctx.scalar(f"{path}/altitude", msg.altitude)


def detected_range(msg) -> tuple[float, bool] | None:
    """(where a Range's detection is, whether that is a measured distance), or None for none: a
    value within [min_range, max_range], measured; a fixed-distance ranger's (min_range ==
    max_range) -inf at that distance, measured (Range.msg; RViz draws it there); a ranging
    sensor's -inf, closer than it can measure (REP 117), at min_range, not a measurement (a
    parking sensor's closest obstacle must not vanish); +inf (nothing in range) and NaN none."""
    if msg.min_range <= msg.range <= msg.max_range:
        return msg.range, True
    if msg.range == -math.inf:
        return msg.min_range, msg.min_range == msg.max_range
    return None


@logger("sensor_msgs/msg/Range")
def log_range(ctx: Context, path: str, msg) -> None:
    """A detection as a point on the sensor's x axis in its frame and, measured, a scalar; no
    detection logs no point (an obstacle gone from a parking sensor must not stay on screen; an
    empty Points3D, not a Clear, which would also clear the entity's coordinate frame)."""
    detected = detected_range(msg)
    if detected is None:
        ctx.log(f"{path}/detection", rr.Points3D(np.empty((0, 3))), frame=msg.header.frame_id)
        return
    distance, measured = detected
    if measured:
        ctx.scalar(f"{path}/range", distance)
    ctx.log(f"{path}/detection", rr.Points3D([[distance, 0.0, 0.0]]), frame=msg.header.frame_id)


BATTERY_SCALARS = ("voltage", "current", "charge", "capacity", "percentage", "temperature",
                   "power_supply_status", "power_supply_health", "present")
MAX_CELLS = 1000  # a message with more cells is refused: each cell is an entity of its own


@logger("sensor_msgs/msg/BatteryState")
def log_battery_state(ctx: Context, path: str, msg) -> None:
    """Its measurements, status and health codes (BatteryState.msg's constants), and each cell's
    voltage and temperature at <topic>/cell_voltage/<i>, <topic>/cell_temperature/<i> (from 0);
    a NaN value (not measured) left out."""
    for series in ("cell_voltage", "cell_temperature"):
        require(len(getattr(msg, series)) <= MAX_CELLS, f"{len(getattr(msg, series))} {series} values: more than "
                                                         f"{MAX_CELLS}")
    for name in BATTERY_SCALARS:
        value = float(getattr(msg, name))
        if math.isfinite(value):
            ctx.scalar(f"{path}/{name}", value)
    for series in ("cell_voltage", "cell_temperature"):
        for i, value in enumerate(getattr(msg, series)):
            if math.isfinite(value):
                ctx.scalar(f"{path}/{series}/{i}", value)


MAX_JOINTS = 1000  # a message naming more is refused: each joint is an entity of its own


@logger("sensor_msgs/msg/JointState")
def log_joint_state(ctx: Context, path: str, msg) -> None:
    """Each joint's position, velocity and effort at <topic>/<joint>/<quantity>, as given: each
    list is empty or holds one value per name."""
    require(len(msg.name) <= MAX_JOINTS, f"{len(msg.name)} joints: more than {MAX_JOINTS}")
    for quantity in ("position", "velocity", "effort"):
        values = getattr(msg, quantity)
        require(not values or len(values) == len(msg.name),
                f"{len(values)} {quantity} values for {len(msg.name)} joint names")
    for i, name in enumerate(msg.name):
        joint = f"{path}/{rr.escape_entity_path_part(name or f'(unnamed {i})')}"  # several may be
        for quantity in ("position", "velocity", "effort"):
            values = getattr(msg, quantity)
            if values:
                ctx.scalar(f"{joint}/{quantity}", values[i])
