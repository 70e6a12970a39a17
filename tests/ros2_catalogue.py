"""One message of every ROS 2 type the viewer logs, with known contents, and what
the .rrd must then hold (archetype and values). Shared by the unit test (loggers
called directly) and the bridge test (published like an rmw_zenoh node)."""
from __future__ import annotations

import io
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from canbench import ros2_msgs as m

Columns = dict[str, dict[str, list]]  # canbench.viewer.read_rrd_columns


@dataclass
class Case:
    topic: str
    type_name: str
    msg: object
    check: Callable[[Columns], None]


def header(frame: str = "") -> m.Header:
    return m.Header(stamp=m.Time(sec=1, nanosec=2), frame_id=frame)


def last(columns: Columns, entity: str, component: str):
    assert entity in columns, f"{entity} not logged (entities: {sorted(columns)})"
    assert component in columns[entity], f"{entity}: no {component} (has {sorted(columns[entity])})"
    return columns[entity][component][-1]


def close(a, b, tol: float = 1e-5) -> bool:
    return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), atol=tol))


def image_pixels(columns: Columns, entity: str, archetype: str = "Image") -> np.ndarray:
    fmt = last(columns, entity, f"{archetype}:format")[0]
    dtype = {6: np.uint8, 8: np.uint16, 34: np.float32}[fmt["channel_datatype"]]  # Rerun's ChannelDatatype
    buffer = np.frombuffer(bytes(last(columns, entity, f"{archetype}:buffer")[0]), dtype=dtype)
    channels = buffer.size // (fmt["width"] * fmt["height"])
    return buffer.reshape(fmt["height"], fmt["width"], channels)


def q_z(deg: float) -> m.Quaternion:
    return m.Quaternion(z=math.sin(math.radians(deg) / 2), w=math.cos(math.radians(deg) / 2))


def tf(parent: str, child: str, xyz, rotation: m.Quaternion | None = None) -> m.TransformStamped:
    return m.TransformStamped(header=header(parent), child_frame_id=child, transform=m.Transform(
        translation=m.Vector3(*xyz), rotation=rotation or m.Quaternion()))


def rgb8_image() -> m.Image:
    """4 x 3 rgb8 with 2 bytes of row padding; pixel (x=2, y=1) = (10, 20, 30)."""
    pixels = np.zeros((3, 4, 3), dtype=np.uint8)
    pixels[1, 2] = (10, 20, 30)
    rows = np.zeros((3, 14), dtype=np.uint8)
    rows[:, :12] = pixels.reshape(3, 12)
    return m.Image(header=header("camera"), height=3, width=4, encoding="rgb8", step=14, data=list(rows.tobytes()))


def mono16_be_image() -> m.Image:
    """2 x 2 big-endian mono16; pixel (1, 0) = 0x1234."""
    return m.Image(header=header("camera"), height=2, width=2, encoding="mono16", is_bigendian=1, step=4,
                   data=list(struct.pack(">4H", 0, 0x1234, 0, 0)))


def depth_image() -> m.Image:
    """2 x 2 16UC1 in millimetres; pixel (0, 1) = 1500 mm."""
    return m.Image(header=header("camera"), height=2, width=2, encoding="16UC1", step=4,
                   data=list(struct.pack("<4H", 0, 0, 1500, 0)))


def png_bytes() -> bytes:
    from PIL import Image
    out = io.BytesIO()
    Image.new("RGB", (2, 2), (1, 2, 3)).save(out, format="PNG")
    return out.getvalue()


PNG = png_bytes()


def cloud_le() -> m.PointCloud2:
    """Two points, x y z float32 at 0/4/8, packed rgb float32 at 16, point_step 20 (padding)."""
    fields = [m.PointField("x", 0, 7, 1), m.PointField("y", 4, 7, 1), m.PointField("z", 8, 7, 1),
              m.PointField("rgb", 16, 7, 1)]
    rgb = struct.unpack("<f", struct.pack("<I", 0x00FF8000))[0]
    data = b"".join(struct.pack("<3f4xf", *p, rgb) for p in [(1.0, 2.0, 3.0), (-1.0, 0.5, 0.0)])
    return m.PointCloud2(header=header("lidar"), height=1, width=2, fields=fields, point_step=20, row_step=40,
                         data=list(data), is_dense=True)


def cloud_be() -> m.PointCloud2:
    """Big-endian, 2 rows x 2 points, intensity float32 at 0, x y z at 4/8/12, a NaN point dropped."""
    fields = [m.PointField("intensity", 0, 7, 1), m.PointField("x", 4, 7, 1), m.PointField("y", 8, 7, 1),
              m.PointField("z", 12, 7, 1)]
    points = [(0.0, 1.0, 1.0, 1.0), (10.0, 2.0, 2.0, 2.0), (5.0, math.nan, 0.0, 0.0), (5.0, 3.0, 3.0, 3.0)]
    data = b"".join(struct.pack(">4f", *p) for p in points)
    return m.PointCloud2(header=header("lidar"), height=2, width=2, fields=fields, is_bigendian=True,
                         point_step=16, row_step=32, data=list(data))


def marker(ns: str, ident: int, kind: int, **kw) -> m.Marker:
    return m.Marker(header=header("base_link"), ns=ns, id=ident, type=kind, **kw)


RED = m.ColorRGBA(1.0, 0.0, 0.0, 1.0)
GREEN = m.ColorRGBA(0.0, 1.0, 0.0, 0.5)


def check_tf(c: Columns) -> None:
    entity = "/tf/map/odom/base_link"
    assert close(last(c, entity, "Transform3D:translation"), [[2.0, 3.0, 0.0]])
    assert last(c, entity, "Transform3D:parent_frame") == ["odom"]
    assert last(c, entity, "Transform3D:child_frame") == ["base_link"]
    assert close(last(c, entity, "Transform3D:quaternion"), [[0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)]])
    assert close(last(c, "/tf/map/odom/base_link/lidar", "Transform3D:translation"), [[0.5, 0.0, 1.0]])


def check_tf_static(c: Columns) -> None:
    # its path depends on whether /tf arrived before: found by its child frame
    found = [e for e, cols in c.items() if cols.get("Transform3D:child_frame", [[None]])[-1] == ["camera"]]
    assert len(found) == 1 and found[0].startswith("/tf/") and found[0].endswith("/base_link/camera"), found
    assert close(last(c, found[0], "Transform3D:translation"), [[0.2, 0.0, 0.5]])


def check_rgb8(c: Columns) -> None:
    px = image_pixels(c, "/ros2/camera/image")
    assert px.shape == (3, 4, 3) and tuple(px[1, 2]) == (10, 20, 30) and px.sum() == 60


def check_bgr8(c: Columns) -> None:
    fmt = last(c, "/ros2/camera/bgr", "Image:format")[0]
    assert fmt["color_model"] == 4  # BGR: Rerun shows it the right way round
    assert tuple(image_pixels(c, "/ros2/camera/bgr")[0, 1]) == (30, 20, 10)


def check_8uc3(c: Columns) -> None:
    fmt = last(c, "/ros2/camera/cv_8uc3", "Image:format")[0]
    assert fmt["color_model"] == 4  # OpenCV's 8UC3 is BGR, as RViz shows it
    assert tuple(image_pixels(c, "/ros2/camera/cv_8uc3")[0, 0]) == (30, 20, 10)


def check_bayer(c: Columns) -> None:
    fmt = last(c, "/ros2/camera/bayer", "Image:format")[0]
    assert fmt["pixel_format"] == 131 and fmt["width"] == 2  # Rerun's BayerGRBG8: it debayers
    assert bytes(last(c, "/ros2/camera/bayer", "Image:buffer")[0]) == bytes([10, 200, 30, 40])


def check_uyvy(c: Columns) -> None:
    fmt = last(c, "/ros2/camera/uyvy", "Image:format")[0]
    assert fmt["pixel_format"] == 27  # Rerun's YUY2: ROS's yuv422 (UYVY) reordered, row padding dropped
    assert bytes(last(c, "/ros2/camera/uyvy", "Image:buffer")[0]) == bytes([16, 128, 235, 100, 81, 90, 145, 240])


def check_mono16(c: Columns) -> None:
    assert image_pixels(c, "/ros2/camera/mono16")[0, 1, 0] == 0x1234


def check_depth(c: Columns) -> None:
    assert image_pixels(c, "/ros2/camera/depth", "DepthImage")[1, 0, 0] == 1500
    assert last(c, "/ros2/camera/depth", "DepthImage:meter") == [1000.0]


def check_depth32(c: Columns) -> None:
    assert close(image_pixels(c, "/ros2/camera/depth32", "DepthImage")[0, 0, 0], 2.5)


def check_compressed(c: Columns) -> None:
    assert bytes(last(c, "/ros2/camera/compressed", "EncodedImage:blob")[0]) == PNG
    assert last(c, "/ros2/camera/compressed", "EncodedImage:media_type") == ["image/png"]


def check_camera_info(c: Columns) -> None:
    k = np.array(last(c, "/ros2/camera/camera_info", "Pinhole:image_from_camera")[0]).reshape(3, 3).T  # column-major
    assert close(k, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    assert close(last(c, "/ros2/camera/camera_info", "Pinhole:resolution"), [[640, 480]])
    assert last(c, "/ros2/camera/camera_info", "CoordinateFrame:frame") == ["camera"]


def check_cloud_le(c: Columns) -> None:
    assert close(last(c, "/ros2/points", "Points3D:positions"), [[1, 2, 3], [-1, 0.5, 0]])
    assert last(c, "/ros2/points", "Points3D:colors") == [0xFF8000FF, 0xFF8000FF]  # RGBA, opaque


def check_cloud_be(c: Columns) -> None:
    assert close(last(c, "/ros2/points_be", "Points3D:positions"), [[1, 1, 1], [2, 2, 2], [3, 3, 3]])
    grey = [v >> 24 for v in last(c, "/ros2/points_be", "Points3D:colors")]
    assert grey == [0, 255, 127]  # intensity 0, 10, 5 scaled to 0..255


def check_scan(c: Columns) -> None:
    # ranges 1 @ 0, 2 @ 90 deg, inf, 0.05 < range_min, nan, 3 @ 450 deg: three points remain
    assert close(last(c, "/ros2/scan", "Points3D:positions"), [[1, 0, 0], [0, 2, 0], [0, 3, 0]], tol=1e-4)


def check_imu(c: Columns) -> None:
    assert c["/ros2/imu/angular_velocity/z"]["Scalars:scalars"] == [[0.3]]
    assert c["/ros2/imu/linear_acceleration/x"]["Scalars:scalars"] == [[9.81]]
    assert close(last(c, "/ros2/imu/orientation", "Transform3D:quaternion"), [[0, 0, math.sin(math.pi / 4),
                                                                              math.cos(math.pi / 4)]])


def check_pose(c: Columns) -> None:
    assert close(last(c, "/ros2/goal", "Transform3D:translation"), [[1, 2, 3]])
    assert last(c, "/ros2/goal", "Transform3D:parent_frame") == ["map"]


def check_odom(c: Columns) -> None:
    assert close(last(c, "/ros2/odom", "Transform3D:translation"), [[4, 5, 0]])
    assert c["/ros2/odom/twist/linear/x"]["Scalars:scalars"] == [[1.5]]
    assert c["/ros2/odom/twist/angular/z"]["Scalars:scalars"] == [[-0.25]]


def check_path(c: Columns) -> None:
    assert close(last(c, "/ros2/plan", "LineStrips3D:strips"), [[[0, 0, 0], [1, 0, 0], [1, 1, 0]]])


def check_grid(c: Columns) -> None:
    px = image_pixels(c, "/ros2/map/image")[:, :, 0]
    # row 0: unknown, free, occupied; row 1: 50 %, free, free
    assert px.tolist() == [[205, 254, 0], [127, 254, 254]]
    assert close(last(c, "/ros2/map", "Transform3D:translation"), [[-1, -2, 0]])
    assert close(last(c, "/ros2/map/plane", "Mesh3D:vertex_positions"), [[0, 0, 0], [1.5, 0, 0], [1.5, 1, 0],
                                                                         [0, 1, 0]])


def check_marker(c: Columns) -> None:
    assert close(last(c, "/ros2/marker/obstacles/1/shape", "Boxes3D:half_sizes"), [[1.0, 0.5, 0.25]])
    assert last(c, "/ros2/marker/obstacles/1/shape", "Boxes3D:colors") == [0xFF0000FF]
    assert close(last(c, "/ros2/marker/obstacles/1", "Transform3D:translation"), [[5, 0, 0]])


def check_markers(c: Columns) -> None:
    base = "/ros2/markers/shapes"
    assert close(last(c, f"{base}/2/shape", "Ellipsoids3D:half_sizes"), [[0.5, 0.5, 0.5]])
    assert last(c, f"{base}/2/shape", "Ellipsoids3D:colors") == [0x00FF0080]
    assert close(last(c, f"{base}/3/shape", "LineStrips3D:strips"), [[[0, 0, 0], [1, 1, 0]]])
    assert close(last(c, f"{base}/4/shape", "Points3D:positions"), [[1, 2, 3]])
    assert last(c, f"{base}/5/shape", "Points3D:labels") == ["hello"]
    assert close(last(c, f"{base}/6/shape", "Arrows3D:vectors"), [[2, 0, 0]])
    assert close(last(c, f"{base}/7/shape", "Cylinders3D:lengths"), [3.0])
    assert "Clear:is_recursive" in c[f"{base}/8"]  # DELETE of marker 8


def check_markers_cleared(c: Columns) -> None:
    assert "Boxes3D:half_sizes" in c["/ros2/markers_cleared/a/1/shape"]
    assert c["/ros2/markers_cleared"]["Clear:is_recursive"] == [[True]]  # DELETEALL: the whole topic


def scalar_is(entity: str, value: float) -> Callable[[Columns], None]:
    def check(c: Columns) -> None:
        assert close(last(c, entity, "Scalars:scalars"), [value]), f"{entity}: {c.get(entity)}"
    return check


def check_fix(c: Columns) -> None:
    assert close(last(c, "/ros2/gnss/fix", "GeoPoints:positions"), [[48.137, 11.575]])
    assert c["/ros2/gnss/fix/altitude"]["Scalars:scalars"] == [[519.5]]
    assert c["/ros2/gnss/fix/status"]["Scalars:scalars"] == [[0.0]]


def check_no_fix(c: Columns) -> None:
    assert "/ros2/gnss/no_fix" not in c  # no point for a receiver without a fix: NaN coordinates
    assert c["/ros2/gnss/no_fix/status"]["Scalars:scalars"] == [[-1.0]]


def check_range(c: Columns) -> None:
    assert close(last(c, "/ros2/park/front_left/range", "Scalars:scalars"), [1.5])
    assert close(last(c, "/ros2/park/front_left/detection", "Points3D:positions"), [[1.5, 0, 0]])
    assert last(c, "/ros2/park/front_left/detection", "CoordinateFrame:frame") == ["sonar_fl"]


def check_battery(c: Columns) -> None:
    assert close(last(c, "/ros2/battery/voltage", "Scalars:scalars"), [12.6])
    assert close(last(c, "/ros2/battery/percentage", "Scalars:scalars"), [0.75])
    assert "/ros2/battery/current" not in c  # NaN: not measured
    assert close(last(c, "/ros2/battery/cell_voltage/1", "Scalars:scalars"), [4.1])
    assert "/ros2/battery/cell_voltage/2" not in c


def check_joints(c: Columns) -> None:
    assert close(last(c, "/ros2/joint_states/steering/position", "Scalars:scalars"), [0.1])
    assert close(last(c, r"/ros2/joint_states/wheel\/fl/position", "Scalars:scalars"), [2.0])
    assert close(last(c, "/ros2/joint_states/steering/velocity", "Scalars:scalars"), [0.5])
    assert "/ros2/joint_states/steering/effort" not in c  # no efforts given


def check_point_stamped(c: Columns) -> None:
    assert close(last(c, "/ros2/clicked_point", "Points3D:positions"), [[1, 2, 0]])
    assert last(c, "/ros2/clicked_point", "CoordinateFrame:frame") == ["map"]


def check_initial_pose(c: Columns) -> None:
    assert close(last(c, "/ros2/initialpose", "Transform3D:translation"), [[3, 4, 0]])
    assert last(c, "/ros2/initialpose", "Transform3D:parent_frame") == ["map"]


def check_pose_array(c: Columns) -> None:
    assert close(last(c, "/ros2/particles", "Arrows3D:origins"), [[0, 0, 0], [1, 1, 0]])
    assert close(last(c, "/ros2/particles", "Arrows3D:vectors"), [[0.3, 0, 0], [0, 0.3, 0]])  # RViz's 0.3 m, 90°


def check_particle_cloud(c: Columns) -> None:
    assert close(last(c, "/ros2/particle_cloud", "Arrows3D:origins"), [[0, 0, 0], [1, 1, 0]])
    assert close(last(c, "/ros2/particle_cloud", "Arrows3D:vectors"), [[0.02, 0, 0], [0, 0.3, 0]])  # by weight


def check_twist_stamped(c: Columns) -> None:
    assert c["/ros2/cmd_vel/linear/x"]["Scalars:scalars"] == [[2.5]]
    assert c["/ros2/cmd_vel/angular/z"]["Scalars:scalars"] == [[0.2]]


def check_diagnostics(c: Columns) -> None:
    engine = c[r"/ros2/diagnostics/ecu\/engine"]
    assert engine["TextLog:text"] == [["coolant too hot (ECU1) temp=110, limit=105"]]
    assert engine["TextLog:level"] == [["ERROR"]]
    assert c[r"/ros2/diagnostics/ecu\/engine/level"]["Scalars:scalars"] == [[2.0]]
    gateway = c["/ros2/diagnostics/gateway"]
    assert (gateway["TextLog:text"], gateway["TextLog:level"]) == ([["[stale] no update"]], [["WARN"]])


CASES = [
    Case("/tf", "tf2_msgs/msg/TFMessage", m.TFMessage(transforms=[
        tf("map", "odom", (1, 0, 0)), tf("odom", "base_link", (2, 3, 0), q_z(90)),
        tf("base_link", "lidar", (0.5, 0, 1))]), check_tf),
    Case("/tf_static", "tf2_msgs/msg/TFMessage", m.TFMessage(transforms=[tf("base_link", "camera", (0.2, 0, 0.5))]),
         check_tf_static),
    Case("/camera/image", "sensor_msgs/msg/Image", rgb8_image(), check_rgb8),
    Case("/camera/bgr", "sensor_msgs/msg/Image", m.Image(header=header(), height=1, width=2, encoding="bgr8", step=6,
                                                         data=[0, 0, 0, 30, 20, 10]), check_bgr8),
    Case("/camera/cv_8uc3", "sensor_msgs/msg/Image", m.Image(header=header(), height=1, width=1, encoding="8UC3",
                                                              step=3, data=[30, 20, 10]), check_8uc3),
    Case("/camera/bayer", "sensor_msgs/msg/Image", m.Image(header=header(), height=2, width=2, encoding="bayer_grbg8",
                                                           step=2, data=[10, 200, 30, 40]), check_bayer),
    Case("/camera/uyvy", "sensor_msgs/msg/Image", m.Image(  # 2 x 2, 2 bytes of padding a row
        header=header(), height=2, width=2, encoding="yuv422", step=6,
        data=[128, 16, 100, 235, 0, 0, 90, 81, 240, 145, 0, 0]), check_uyvy),
    Case("/camera/mono16", "sensor_msgs/msg/Image", mono16_be_image(), check_mono16),
    Case("/camera/depth", "sensor_msgs/msg/Image", depth_image(), check_depth),
    Case("/camera/depth32", "sensor_msgs/msg/Image", m.Image(header=header(), height=1, width=1, encoding="32FC1",
                                                             step=4, data=list(struct.pack("<f", 2.5))), check_depth32),
    Case("/camera/compressed", "sensor_msgs/msg/CompressedImage",
         m.CompressedImage(header=header("camera"), format="png", data=list(PNG)), check_compressed),
    Case("/camera/camera_info", "sensor_msgs/msg/CameraInfo", m.CameraInfo(
        header=header("camera"), height=480, width=640, distortion_model="plumb_bob", d=[0.0] * 5,
        k=[500.0, 0, 320, 0, 510, 240, 0, 0, 1]), check_camera_info),
    Case("/points", "sensor_msgs/msg/PointCloud2", cloud_le(), check_cloud_le),
    Case("/points_be", "sensor_msgs/msg/PointCloud2", cloud_be(), check_cloud_be),
    Case("/scan", "sensor_msgs/msg/LaserScan", m.LaserScan(
        header=header("lidar"), angle_min=0.0, angle_max=2 * math.pi, angle_increment=math.pi / 2, range_min=0.1,
        range_max=10.0, ranges=[1.0, 2.0, math.inf, 0.05, math.nan, 3.0]), check_scan),
    Case("/imu", "sensor_msgs/msg/Imu", m.Imu(header=header("base_link"), orientation=q_z(90),
                                              angular_velocity=m.Vector3(0.1, 0.2, 0.3),
                                              linear_acceleration=m.Vector3(9.81, 0, 0)), check_imu),
    Case("/goal", "geometry_msgs/msg/PoseStamped",
         m.PoseStamped(header=header("map"), pose=m.Pose(position=m.Point(1, 2, 3))), check_pose),
    Case("/odom", "nav_msgs/msg/Odometry", m.Odometry(
        header=header("odom"), child_frame_id="base_link",
        pose=m.PoseWithCovariance(pose=m.Pose(position=m.Point(4, 5, 0))),
        twist=m.TwistWithCovariance(twist=m.Twist(linear=m.Vector3(1.5, 0, 0), angular=m.Vector3(0, 0, -0.25)))),
         check_odom),
    Case("/plan", "nav_msgs/msg/Path", m.Path(header=header("map"), poses=[
        m.PoseStamped(pose=m.Pose(position=m.Point(*p))) for p in [(0, 0, 0), (1, 0, 0), (1, 1, 0)]]), check_path),
    Case("/map", "nav_msgs/msg/OccupancyGrid", m.OccupancyGrid(
        header=header("map"), info=m.MapMetaData(resolution=0.5, width=3, height=2,
                                                 origin=m.Pose(position=m.Point(-1, -2, 0))),
        data=[-1, 0, 100, 50, 0, 0]), check_grid),
    Case("/marker", "visualization_msgs/msg/Marker", marker("obstacles", 1, 1, pose=m.Pose(position=m.Point(5, 0, 0)),
                                                          scale=m.Vector3(2, 1, 0.5), color=RED), check_marker),
    Case("/markers", "visualization_msgs/msg/MarkerArray", m.MarkerArray(markers=[
        marker("shapes", 2, 2, scale=m.Vector3(1, 1, 1), color=GREEN),
        marker("shapes", 3, 4, scale=m.Vector3(0.1, 0, 0), color=RED, points=[m.Point(0, 0, 0), m.Point(1, 1, 0)]),
        marker("shapes", 4, 8, scale=m.Vector3(0.2, 0.2, 0), color=RED, points=[m.Point(1, 2, 3)]),
        marker("shapes", 5, 9, scale=m.Vector3(0, 0, 0.5), color=RED, text="hello"),
        marker("shapes", 6, 0, scale=m.Vector3(2, 0.1, 0.1), color=RED),
        marker("shapes", 7, 3, scale=m.Vector3(1, 1, 3), color=RED),
        marker("shapes", 8, 1, scale=m.Vector3(1, 1, 1), color=RED),
        marker("shapes", 8, 1, action=2)]), check_markers),
    Case("/markers_cleared", "visualization_msgs/msg/MarkerArray", m.MarkerArray(markers=[
        marker("a", 1, 1, scale=m.Vector3(1, 1, 1), color=RED), marker("", 0, 0, action=3)]), check_markers_cleared),
    Case("/chatter", "std_msgs/msg/String", m.String("hello viewer"),
         lambda c: c["/ros2/chatter"]["TextLog:text"] == [["hello viewer"]] or _fail(c, "/ros2/chatter")),
    Case("/cabin/temperature", "sensor_msgs/msg/Temperature", m.Temperature(temperature=21.5),
         lambda c: c["/ros2/cabin/temperature/temperature"]["Scalars:scalars"] == [[21.5]] or _fail(c, "temp")),
    Case("/cabin/pressure", "sensor_msgs/msg/FluidPressure", m.FluidPressure(fluid_pressure=101325.0),
         lambda c: c["/ros2/cabin/pressure/fluid_pressure"]["Scalars:scalars"] == [[101325.0]] or _fail(c, "p")),
    Case("/cabin/humidity", "sensor_msgs/msg/RelativeHumidity", m.RelativeHumidity(relative_humidity=0.4),
         lambda c: c["/ros2/cabin/humidity/relative_humidity"]["Scalars:scalars"] == [[0.4]] or _fail(c, "h")),
    Case("/cabin/light", "sensor_msgs/msg/Illuminance", m.Illuminance(illuminance=300.0),
         lambda c: c["/ros2/cabin/light/illuminance"]["Scalars:scalars"] == [[300.0]] or _fail(c, "lux")),
    Case("/gnss/fix", "sensor_msgs/msg/NavSatFix", m.NavSatFix(
        header=header("gnss"), status=m.NavSatStatus(status=0, service=1), latitude=48.137, longitude=11.575,
        altitude=519.5), check_fix),
    Case("/gnss/no_fix", "sensor_msgs/msg/NavSatFix", m.NavSatFix(
        header=header("gnss"), status=m.NavSatStatus(status=-1), latitude=math.nan, longitude=math.nan,
        altitude=math.nan), check_no_fix),
    Case("/park/front_left", "sensor_msgs/msg/Range", m.Range(
        header=header("sonar_fl"), field_of_view=0.5, min_range=0.2, max_range=4.0, range=1.5), check_range),
    Case("/battery", "sensor_msgs/msg/BatteryState", m.BatteryState(
        header=header(), voltage=12.6, current=math.nan, percentage=0.75, temperature=math.nan,
        cell_voltage=[4.2, 4.1, math.nan]), check_battery),
    Case("/joint_states", "sensor_msgs/msg/JointState", m.JointState(
        header=header(), name=["steering", "wheel/fl"], position=[0.1, 2.0], velocity=[0.5, 30.0]), check_joints),
    Case("/clicked_point", "geometry_msgs/msg/PointStamped", m.PointStamped(header=header("map"),
                                                                            point=m.Point(1, 2, 0)),
         check_point_stamped),
    Case("/initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped", m.PoseWithCovarianceStamped(
        header=header("map"), pose=m.PoseWithCovariance(pose=m.Pose(position=m.Point(3, 4, 0)))), check_initial_pose),
    Case("/particles", "geometry_msgs/msg/PoseArray", m.PoseArray(header=header("map"), poses=[
        m.Pose(), m.Pose(position=m.Point(1, 1, 0), orientation=q_z(90))]), check_pose_array),
    Case("/particle_cloud", "nav2_msgs/msg/ParticleCloud", m.ParticleCloud(header=header("map"), particles=[
        m.Particle(m.Pose(), 0.0), m.Particle(m.Pose(position=m.Point(1, 1, 0), orientation=q_z(90)), 1.0)]),
         check_particle_cloud),
    Case("/cmd_vel", "geometry_msgs/msg/TwistStamped", m.TwistStamped(
        header=header("base_link"), twist=m.Twist(linear=m.Vector3(2.5, 0, 0), angular=m.Vector3(0, 0, 0.2))),
         check_twist_stamped),
    Case("/accel", "geometry_msgs/msg/AccelStamped", m.AccelStamped(
        header=header("base_link"), accel=m.Accel(linear=m.Vector3(0, 0, 9.81))),
         scalar_is("/ros2/accel/linear/z", 9.81)),
    Case("/imu/mag", "sensor_msgs/msg/MagneticField", m.MagneticField(
        header=header("imu"), magnetic_field=m.Vector3(2e-5, 0, -4e-5)),
         scalar_is("/ros2/imu/mag/magnetic_field/z", -4e-5)),
    Case("/wheel/twist", "geometry_msgs/msg/TwistWithCovarianceStamped", m.TwistWithCovarianceStamped(
        header=header("base_link"), twist=m.TwistWithCovariance(twist=m.Twist(linear=m.Vector3(3.5, 0, 0)))),
         scalar_is("/ros2/wheel/twist/linear/x", 3.5)),
    Case("/accel/filtered", "geometry_msgs/msg/AccelWithCovarianceStamped", m.AccelWithCovarianceStamped(
        header=header("base_link"), accel=m.AccelWithCovariance(accel=m.Accel(linear=m.Vector3(0.5, 0, 0)))),
         scalar_is("/ros2/accel/filtered/linear/x", 0.5)),
    Case("/hitch/wrench", "geometry_msgs/msg/WrenchStamped", m.WrenchStamped(
        header=header("hitch"), wrench=m.Wrench(force=m.Vector3(0, 0, -1200.0))),
         scalar_is("/ros2/hitch/wrench/force/z", -1200.0)),
    Case("/footprint", "geometry_msgs/msg/PolygonStamped", m.PolygonStamped(
        header=header("base_link"), polygon=m.Polygon(points=[m.Point32(1, 1, 0), m.Point32(-1, 1, 0),
                                                              m.Point32(-1, -1, 0)])),
         lambda c: close(last(c, "/ros2/footprint", "LineStrips3D:strips"),
                         [[[1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, 1, 0]]]) or _fail(c, "footprint")),
    Case("/magnet", "geometry_msgs/msg/Vector3Stamped", m.Vector3Stamped(
        header=header("imu"), vector=m.Vector3(0.2, 0, 0)), scalar_is("/ros2/magnet/x", 0.2)),
    Case("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", m.DiagnosticArray(header=header(), status=[
        m.DiagnosticStatus(level=2, name="ecu/engine", message="coolant too hot", hardware_id="ECU1",
                           values=[m.KeyValue("temp", "110"), m.KeyValue("limit", "105")]),
        m.DiagnosticStatus(level=3, name="gateway", message="no update")]), check_diagnostics),
    *[Case(f"/numbers/{name.lower()}", f"std_msgs/msg/{name}", getattr(m, name)(value),
           scalar_is(f"/ros2/numbers/{name.lower()}", float(value)))
      for name, value in (("Bool", True), ("Int8", -5), ("Int16", -300), ("Int32", -70000), ("Int64", -2**40),
                          ("UInt8", 200), ("UInt16", 60000), ("UInt32", 4_000_000_000), ("UInt64", 2**40),
                          ("Float32", 1.5))],
    Case("/vehicle/can_in", "can_msgs/msg/Frame", m.CanFrame(id=0x0C0, dlc=8, data=bytes.fromhex("C1E803000000000B")),
         lambda c: c["/ros2/vehicle/can_in/0C0/raw"]["TextLog:text"] == [["0C0#C1E803000000000B"]] or _fail(c, "can")),
]


def _fail(columns: Columns, what: str) -> None:
    raise AssertionError(f"{what}: {[(e, v) for e, v in columns.items() if what in e]}")


def malformed_variants(payload: bytes) -> list[bytes]:
    """Truncations, wrong encapsulations and, at every 4-byte-aligned offset past the header,
    a length of 0xFFFFFFF0 (whatever field sits there: sequence and string lengths among them)."""
    variants = [b"", payload[:3], payload[:4], payload[:len(payload) // 2], payload[:-1],
                b"\x00\x03\x00\x00" + payload[4:], b"\x01\x00\x00\x00" + payload[4:], b"\x00\x11" + payload[2:]]
    step = max(4, (len(payload) // 64) // 4 * 4)  # big payloads: 64 offsets spread over them
    for offset in range(4, len(payload) - 3, step):
        variants.append(payload[:offset] + struct.pack("<I", 0xFFFFFFF0) + payload[offset + 4:])
    return variants
