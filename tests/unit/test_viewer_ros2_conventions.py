"""ROS 2 conventions real publishers follow that the viewer read wrong: a TF frame whose
ancestors become known later (amcl's map -> odom after odom -> base_link), an IMU without an
orientation estimate (Imu.msg: covariance[0] -1), a cloud with PCL's '_' padding fields, the
depth rmw_zenoh leaves out of a token's QoS. Payloads are rosbags' CDR (an implementation of
its own), embedded as hex so the test needs no rosbags."""
from __future__ import annotations

import pytest

from canbench import ros2
from canbench import ros2_msgs as m

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from rrd_logged import logged  # noqa: E402


def tf(parent: str, child: str, x: float) -> bytes:
    return m.TFMessage([m.TransformStamped(header=m.Header(frame_id=parent), child_frame_id=child,
                                           transform=m.Transform(translation=m.Vector3(x, 0, 0)))]).serialize()


def test_a_frame_stays_on_one_entity_when_its_ancestors_become_known(tmp_path):
    """odom -> base_link flows before localisation starts, then amcl publishes map -> odom: base_link
    moved from tf/odom/base_link to tf/map/odom/base_link, and Rerun takes a child frame from two
    temporal entities as a data error ("Two entities define the same child frame", re_tf's
    cached_transforms_for_timeline.rs): it resolves the frame on the first entity only."""
    TF = "tf2_msgs/msg/TFMessage"
    columns, errors = logged(tmp_path, [(TF, "ros2/tf", tf("odom", "base_link", 1.0)),
                                        (TF, "ros2/tf", tf("map", "odom", 5.0)),
                                        (TF, "ros2/tf", tf("odom", "base_link", 2.0))])
    assert not errors
    defining = {e: c["Transform3D:translation"] for e, c in columns.items()
                if ["base_link"] in c.get("Transform3D:child_frame", [])}
    assert list(defining) == ["/tf/odom/base_link"]
    assert [row[0][0] for row in defining["/tf/odom/base_link"]] == [1.0, 2.0]
    assert columns["/tf/map/odom"]["Transform3D:parent_frame"] == [["map"]]


# rosbags 0.11.9 (Stores.ROS2_JAZZY), serialize_cdr(Imu, little endian): header (1700000000 s, 5 ns,
# 'imu_link'), orientation (0, 0, 0, 0) with orientation_covariance[0] -1 (no estimate), angular
# velocity (0.1, 0.2, 0.3), linear acceleration (0, 0, 9.81) with linear_acceleration_covariance[0] -1
IMU_WITHOUT_ORIENTATION = bytes.fromhex(
    "0001000000f153650500000009000000696d755f6c696e6b000000000000000000000000000000000000000000000000000000000000"
    "000000000000000000000000f0bf00000000000000000000000000000000000000000000000000000000000000000000000000000000"
    "0000000000000000000000000000000000000000000000009a9999999999b93f9a9999999999c93f333333333333d33f000000000000"
    "000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000"
    "000000000000000000000000000000000000000000000000000000001f85eb51b89e2340000000000000f0bf00000000000000000000"
    "000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000")


def test_an_imu_without_an_estimate_draws_none_of_it(tmp_path):
    """Imu.msg: "please check for a value of -1 in the first element of each covariance matrix, and
    disregard the associated estimate". A raw IMU (imu/data_raw) sends no orientation: its zero
    quaternion was drawn as an orientation (and a default w=1 one would read as level)."""
    msg = m.decode("sensor_msgs/msg/Imu", IMU_WITHOUT_ORIENTATION)
    assert msg.orientation_covariance[0] == -1 and msg.angular_velocity.y == 0.2  # the vector as generated
    columns, errors = logged(tmp_path, [("sensor_msgs/msg/Imu", "ros2/imu/data_raw", IMU_WITHOUT_ORIENTATION)])
    assert not errors
    assert sorted(e for e in columns if e.startswith("/ros2/")) == [
        "/ros2/imu/data_raw/angular_velocity/x", "/ros2/imu/data_raw/angular_velocity/y",
        "/ros2/imu/data_raw/angular_velocity/z"]


# rosbags 0.11.9 (Stores.ROS2_JAZZY), serialize_cdr(PointCloud2, little endian): header (1700000000 s,
# 5 ns, 'lidar'), 1 x 2 points of 32 bytes as a PCD with padding loads (pcl_ros' pcd_to_pointcloud):
# fields x y z float32 at 0 4 8, '_' int8 x4 at 12, rgb float32 at 16, '_' int8 x12 at 20; points
# (1, 2, 3) red and (4, 5, 6) green
CLOUD_WITH_PADDING_FIELDS = bytes.fromhex(
    "0001000000f1536505000000060000006c69646172000000010000000200000006000000020000007800000000000000070000000100"
    "00000200000079000000040000000700000001000000020000007a000000080000000700000001000000020000005f0000000c000000"
    "01000000040000000400000072676200100000000700000001000000020000005f00000014000000010000000c000000000000002000"
    "000040000000400000000000803f0000004000004040000000000000ff00000000000000000000000000000080400000a0400000c040"
    "0000000000ff000000000000000000000000000001")


def test_a_cloud_with_two_padding_fields_is_drawn(tmp_path):
    """Two fields of one name ('_', PCL's padding) made the numpy layout refuse the whole cloud;
    RViz reads the fields it needs (the first of a name) and passes over the others."""
    columns, errors = logged(tmp_path, [("sensor_msgs/msg/PointCloud2", "ros2/points", CLOUD_WITH_PADDING_FIELDS)])
    assert not errors
    assert columns["/ros2/points"]["Points3D:positions"] == [[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]]
    red, green = 0xFF0000FF, 0x00FF00FF  # Rerun's colours are 0xRRGGBBAA
    assert columns["/ros2/points"]["Points3D:colors"] == [[red, green]]


@pytest.mark.parametrize("qos,depth", [(":1:,:,:,:,,", 42), (":1:,42:,:,:,,", 42), (":1:,10:,:,:,,", 10)])
def test_a_depth_left_out_of_the_token_is_rmw_zenohs_default(qos, depth):
    """rmw_zenoh writes a QoS field only where it differs from its own defaults (qos_to_keyexpr),
    and its default depth is 42 (RMW_ZENOH_DEFAULT_HISTORY_DEPTH, rmw_zenoh_cpp/src/detail/qos.cpp),
    not rmw's 10: a publisher keeping 42 samples for late subscribers was asked for 10."""
    token = ros2.publisher_token(0, "z", 0, 1, "/", "map_server", "/map", "nav_msgs/msg/OccupancyGrid", "RIHS01_0",
                                 qos)
    assert ros2.parse_token(token).transient_local_depth == depth
