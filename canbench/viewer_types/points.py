"""Point sets: sensor_msgs/PointCloud2 (any field layout) and LaserScan (polar ranges)."""
from __future__ import annotations

import numpy as np
import rerun as rr

from .registry import Context, logger, require

# PointField datatype -> numpy element type (sensor_msgs/msg/PointField.msg)
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
PACKED_COLOURS = ("rgba", "rgb")
USED_FIELDS = ("x", "y", "z", *PACKED_COLOURS, "intensity")  # what log_point_cloud draws


def cloud_fields(msg) -> dict[str, np.ndarray]:
    """Field name -> one value per point (first element of each field) of the fields the logger
    draws (USED_FIELDS; of two of one name the first, as RViz finds them), any offsets,
    point_step, row_step and byte order; refuses layouts that read past the data. The others
    are passed over: PCL's padding fields all share the name '_', which one numpy layout refused."""
    require(msg.point_step > 0, "point_step 0")
    require(msg.row_step >= msg.width * msg.point_step, f"row_step {msg.row_step} < width * point_step")
    require(len(msg.data) >= msg.row_step * msg.height, f"{len(msg.data)} data bytes < row_step * height")
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.name not in USED_FIELDS or f.name in names:
            continue
        if f.datatype not in DATATYPES:
            raise ValueError(f"point field {f.name!r}: unknown datatype {f.datatype}")
        # PCL packs a colour's bits in a float32 field (0xAARRGGBB: red >= 128 is a NaN): read as
        # bits, since a float conversion quiets a signalling NaN, and red 128..191 would gain 64
        kind = "u4" if f.name in PACKED_COLOURS and DATATYPES[f.datatype] == "f4" else DATATYPES[f.datatype]
        dtype = np.dtype(order + kind)
        require(f.offset + dtype.itemsize <= msg.point_step, f"field {f.name!r} ends past point_step")
        names.append(f.name)
        formats.append(dtype)
        offsets.append(f.offset)
    layout = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step})
    rows = np.frombuffer(bytes(msg.data), dtype=np.uint8)[:msg.row_step * msg.height].reshape(msg.height, msg.row_step)
    points = rows[:, :msg.width * msg.point_step].copy().view(layout).reshape(-1)
    return {n: points[n].astype(np.float64 if points[n].dtype.kind == "f" else points[n].dtype.newbyteorder("="))
            for n in names}


def cloud_colors(fields: dict[str, np.ndarray]) -> np.ndarray | None:
    """rgb / rgba packed in 32 bits (PCL's convention, also as float32 bits), else intensity as grey."""
    for name in PACKED_COLOURS:
        if name in fields:
            packed = fields[name]  # float32 fields come as their bits (cloud_fields)
            bits = packed.astype(np.float32).view(np.uint32) if packed.dtype.kind == "f" else packed.astype(np.uint32)
            rgb = np.stack([(bits >> 16) & 0xFF, (bits >> 8) & 0xFF, bits & 0xFF], axis=1)
            alpha = (bits >> 24) & 0xFF if name == "rgba" else np.full(len(bits), 255)
            return np.column_stack([rgb, alpha]).astype(np.uint8)
    if "intensity" in fields and len(fields["intensity"]):
        i = fields["intensity"].astype(np.float64)
        finite = np.isfinite(i)  # a NaN made the span NaN and the whole cloud one grey; it is black alone
        low, high = (i[finite].min(), i[finite].max()) if finite.any() else (0.0, 0.0)
        span = high - low
        grey = np.where(finite, (i - low) / span * 255 if span > 0 else 255.0, 0.0)
        grey = np.clip(np.nan_to_num(grey), 0, 255).astype(np.uint8)
        return np.stack([grey, grey, grey], axis=1)
    return None


@logger("sensor_msgs/msg/PointCloud2")
def log_point_cloud(ctx: Context, path: str, msg) -> None:
    fields = cloud_fields(msg)
    require({"x", "y", "z"} <= set(fields), f"point cloud without x, y, z (fields: {', '.join(fields)})")
    xyz = np.stack([fields["x"], fields["y"], fields["z"]], axis=1).astype(np.float32)
    valid = np.isfinite(xyz).all(axis=1)  # not dense: NaN marks a missing point
    colors = cloud_colors(fields)
    ctx.log(path, rr.Points3D(xyz[valid], colors=None if colors is None else colors[valid]),
            frame=msg.header.frame_id)


@logger("sensor_msgs/msg/LaserScan")
def log_laser_scan(ctx: Context, path: str, msg) -> None:
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    angles = msg.angle_min + np.arange(len(ranges)) * msg.angle_increment
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(ranges) & (ranges >= msg.range_min) & (ranges <= msg.range_max)
    r, a = ranges[keep], angles[keep]
    xyz = np.stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))], axis=1)
    ctx.log(path, rr.Points3D(xyz), frame=msg.header.frame_id)
