"""Cameras and maps: sensor_msgs/Image (colour, mono, depth), CompressedImage,
CameraInfo (a pinhole), nav_msgs/OccupancyGrid (a grey image, placed in 3D)."""
from __future__ import annotations

import numpy as np
import rerun as rr

from .registry import Context, logger, require

# encoding -> (numpy element type, channels, how Rerun shows it: a colour model, a pixel format it
# decodes itself, or None for a depth image; metres per unit of a depth image). OpenCV's type names
# are read as RViz reads them (rviz_default_plugins, ros_image_texture.cpp): 8UC3 BGR, 8UC4 BGRA,
# 8UC1 grey; a 16-bit Bayer mosaic is shown raw, 16-bit grey (RViz reads every Bayer image as 8-bit grey).
ENCODINGS: dict[str, tuple[str, int, str | rr.PixelFormat | None, float]] = {
    "rgb8": ("u1", 3, "RGB", 0), "rgba8": ("u1", 4, "RGBA", 0), "bgr8": ("u1", 3, "BGR", 0),
    "bgra8": ("u1", 4, "BGRA", 0), "mono8": ("u1", 1, "L", 0), "mono16": ("u2", 1, "L", 0),
    "8UC1": ("u1", 1, "L", 0), "8UC3": ("u1", 3, "BGR", 0), "8UC4": ("u1", 4, "BGRA", 0),
    "bayer_rggb8": ("u1", 1, rr.PixelFormat.BayerRGGB8, 0), "bayer_bggr8": ("u1", 1, rr.PixelFormat.BayerBGGR8, 0),
    "bayer_gbrg8": ("u1", 1, rr.PixelFormat.BayerGBRG8, 0), "bayer_grbg8": ("u1", 1, rr.PixelFormat.BayerGRBG8, 0),
    "bayer_rggb16": ("u2", 1, "L", 0), "bayer_bggr16": ("u2", 1, "L", 0),
    "bayer_gbrg16": ("u2", 1, "L", 0), "bayer_grbg16": ("u2", 1, "L", 0),
    # 4:2:2, two bytes a pixel: yuv422 is UYVY (U Y0 V Y1), reordered to the YUY2 Rerun decodes
    # (uyvy and yuyv: their names since ROS 2 Iron, the same bytes)
    "yuv422": ("u1", 2, rr.PixelFormat.YUY2, 0), "yuv422_yuy2": ("u1", 2, rr.PixelFormat.YUY2, 0),
    "uyvy": ("u1", 2, rr.PixelFormat.YUY2, 0), "yuyv": ("u1", 2, rr.PixelFormat.YUY2, 0),
    "16UC1": ("u2", 1, None, 1000.0), "32FC1": ("f4", 1, None, 1.0),  # REP 118: depth in mm or m
}
UYVY_AS_YUY2 = [1, 0, 3, 2]  # byte order of each two pixels


def image_array(msg) -> tuple[np.ndarray, str | rr.PixelFormat | None, float]:
    """(height x width [x channels] array, how Rerun shows it, meter) of a sensor_msgs/Image."""
    if msg.encoding not in ENCODINGS:
        raise ValueError(f"image encoding {msg.encoding!r} not supported (known: {', '.join(ENCODINGS)})")
    kind, channels, shown, meter = ENCODINGS[msg.encoding]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    row = msg.width * channels * dtype.itemsize
    require(msg.width > 0 and msg.height > 0, f"empty image {msg.width}x{msg.height}")
    require(shown != rr.PixelFormat.YUY2 or msg.width % 2 == 0, f"{msg.encoding}: odd width {msg.width}")
    require(msg.step >= row, f"step {msg.step} < width * pixel size {row}")
    require(len(msg.data) >= msg.step * msg.height,
            f"{len(msg.data)} data bytes < step {msg.step} * height {msg.height}")
    rows = np.frombuffer(bytes(msg.data), dtype=np.uint8)[:msg.step * msg.height].reshape(msg.height, msg.step)
    if msg.encoding in ("yuv422", "uyvy"):
        return rows[:, :row].reshape(msg.height, msg.width // 2, 4)[:, :, UYVY_AS_YUY2].copy(), shown, meter
    pixels = rows[:, :row].copy().view(dtype).astype(dtype.newbyteorder("="))
    return pixels.reshape(msg.height, msg.width, channels) if channels > 1 else pixels, shown, meter


@logger("sensor_msgs/msg/Image")
def log_image(ctx: Context, path: str, msg) -> None:
    pixels, shown, meter = image_array(msg)
    archetype: rr.Image | rr.DepthImage
    if shown is None:
        archetype = rr.DepthImage(pixels, meter=meter)
    elif isinstance(shown, rr.PixelFormat):  # Rerun debayers or converts from YUV itself
        archetype = rr.Image(bytes=pixels.tobytes(), width=msg.width, height=msg.height, pixel_format=shown)
    else:  # explicit sizes: from an array's shape alone Rerun would take a 1-pixel-high image for 2D
        archetype = rr.Image(bytes=pixels.tobytes(), width=msg.width, height=msg.height,
                             color_model=shown, datatype=pixels.dtype.type)  # type: ignore[arg-type]
    ctx.log(path, archetype)  # no coordinate frame: an image is 2D; CameraInfo's pinhole carries the camera's


MEDIA_TYPES = {"jpeg": "image/jpeg", "jpg": "image/jpeg", "png": "image/png"}


@logger("sensor_msgs/msg/CompressedImage")
def log_compressed_image(ctx: Context, path: str, msg) -> None:
    # format is "jpeg", "png", or image_transport's "<encoding>; jpeg compressed <encoding>"
    words = msg.format.replace(";", " ").lower().split()
    if "compresseddepth" in words:  # compressed_depth_image_transport: a 12-byte ConfigHeader, then the codec's bytes
        raise ValueError(f"compressed image format {msg.format!r}: compressedDepth (a depth image behind its "
                         "transport's own header) is not shown")
    media = next((MEDIA_TYPES[w] for w in words if w in MEDIA_TYPES), None)
    if media is None:
        raise ValueError(f"compressed image format {msg.format!r} is neither jpeg nor png")
    ctx.log(path, rr.EncodedImage(contents=bytes(msg.data), media_type=media))


@logger("sensor_msgs/msg/CameraInfo")
def log_camera_info(ctx: Context, path: str, msg) -> None:
    if not any(msg.k):
        return  # an uncalibrated camera (CameraInfo.msg: K all zero): no pinhole to draw, nothing wrong
    require(msg.k[0] > 0 and msg.k[4] > 0, f"camera matrix without focal lengths: {msg.k}")
    ctx.log(path, rr.Pinhole(image_from_camera=np.array(msg.k).reshape(3, 3), width=msg.width, height=msg.height),
            frame=msg.header.frame_id)


UNKNOWN_GREY = 205  # map_server's grey for unknown cells; no occupancy 0..100 maps to it


# an occupancy's grey by its int8 value's byte (a table: a 4000 x 4000 map in milliseconds, not 0.6 s):
# 0 (free) 254, 100 (occupied) 0, in between proportionally (map_server's scale); -1 and values
# outside 0..100 unknown (205)
GREY_OF_BYTE = np.full(256, UNKNOWN_GREY, dtype=np.uint8)
GREY_OF_BYTE[:101] = np.rint(254 * (100 - np.arange(101)) / 100).astype(np.uint8)


def occupancy_grey(values: np.ndarray) -> np.ndarray:
    """The grey of each cell of an int8 occupancy array (GREY_OF_BYTE)."""
    return GREY_OF_BYTE[values.astype(np.int8).view(np.uint8)]


@logger("nav_msgs/msg/OccupancyGrid")
def log_occupancy_grid(ctx: Context, path: str, msg) -> None:
    w, h, res = msg.info.width, msg.info.height, msg.info.resolution
    require(w > 0 and h > 0 and res > 0, f"empty grid {w}x{h} at resolution {res}")
    require(len(msg.data) == w * h, f"{len(msg.data)} cells != width {w} * height {h}")
    grey = occupancy_grey(np.asarray(msg.data, dtype=np.int8).reshape(h, w))
    ctx.log(f"{path}/image", rr.Image(grey, color_model="L"))
    # in 3D: the origin's pose, then a quad of width * resolution by height * resolution
    # textured with the grid (row 0 at y = 0, as the cells are laid out)
    ctx.pose(path, msg.info.origin.position, msg.info.origin.orientation, msg.header.frame_id)
    x, y = w * res, h * res
    ctx.log(f"{path}/plane", rr.Mesh3D(vertex_positions=[[0, 0, 0], [x, 0, 0], [x, y, 0], [0, y, 0]],
                                       triangle_indices=[[0, 1, 2], [0, 2, 3]],
                                       vertex_texcoords=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                       albedo_texture=np.dstack([grey] * 3)),
            frame=path if msg.header.frame_id else "", named=True)  # the frame the pose above named
