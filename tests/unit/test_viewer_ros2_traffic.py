"""ROS 2 traffic as real nodes send it, which the viewer drew wrong: PCL's colour clouds (rgb bits
in a float32 field, red >= 128 a NaN), a MarkerArray holding a mesh, DELETEALL of one namespace,
TF frames with ROS 1's leading '/', strings that are not UTF-8 (C++ nodes send any bytes), a
liveliness token whose domain is not an ASCII number, compressedDepth images, the QoS of a
TRANSIENT_LOCAL publisher. Each read as the real tools read it (PCL, RViz, tf2, rclpy, rmw_zenoh)."""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from canbench import ros2
from canbench import ros2_msgs as m

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from rrd_logged import logged  # noqa: E402

from canbench.viewer import read_rrd_columns  # noqa: E402
from canbench.viewer_types.points import cloud_colors, cloud_fields  # noqa: E402


@pytest.mark.parametrize("red", [0x00, 0x7F, 0x80, 0xBF, 0xC0, 0xFF])
def test_a_pcl_colour_cloud_keeps_its_red(red):
    # pcl::toROSMsg(PointXYZRGB): x y z, 4 bytes pad, rgb as float32 bits 0xAARRGGBB (a = 255)
    bits = 0xFF000000 | red << 16 | 0xC0 << 8 | 0x20
    F = m.PointField
    for order, big in (("<", False), (">", True)):
        point = struct.pack(f"{order}fff4xI12x", 1.0, 2.0, 3.0, bits)
        msg = m.PointCloud2(header=m.Header(frame_id="camera"), height=1, width=1, is_bigendian=big,
                            fields=[F("x", 0, 7, 1), F("y", 4, 7, 1), F("z", 8, 7, 1), F("rgb", 16, 7, 1)],
                            point_step=32, row_step=32, data=list(point), is_dense=True)
        colours = cloud_colors(cloud_fields(m.decode("sensor_msgs/msg/PointCloud2", msg.serialize())))
        assert colours is not None and list(colours[0]) == [red, 0xC0, 0x20, 255], (order, hex(bits))


def marker(ns: str, ident: int, kind: int = 1, action: int = 0) -> m.Marker:
    return m.Marker(header=m.Header(frame_id="map"), ns=ns, id=ident, type=kind, action=action,
                    scale=m.Vector3(1, 1, 1), color=m.ColorRGBA(1, 0, 0, 1), mesh_resource="package://r/a.dae")


def test_a_marker_array_with_a_mesh_draws_the_others_and_counts_the_array(tmp_path):
    array = m.MarkerArray([marker("robot", 0), marker("robot", 1, kind=10), marker("robot", 2, kind=2),
                           marker("robot", 3)])
    columns, errors = logged(tmp_path, [("visualization_msgs/msg/MarkerArray", "ros2/viz", array)])
    drawn = {e for e in columns if e.startswith("/ros2/viz/robot/") and e.endswith("/shape")}
    assert drawn == {"/ros2/viz/robot/0/shape", "/ros2/viz/robot/2/shape", "/ros2/viz/robot/3/shape"}
    assert errors == ["1 of 4 markers not shown: marker robot/1: MESH_RESOURCE ('package://r/a.dae') is not shown"]


def test_deleteall_of_a_namespace_clears_that_namespace_only(tmp_path):
    columns, errors = logged(tmp_path, [("visualization_msgs/msg/Marker", "ros2/viz", marker("a", 1)),
                                        ("visualization_msgs/msg/Marker", "ros2/viz", marker("b", 1)),
                                        ("visualization_msgs/msg/Marker", "ros2/viz", marker("b", 0, action=3)),
                                        ("visualization_msgs/msg/Marker", "ros2/viz", marker("", 0, action=3))])
    cleared = sorted(e for e, values in columns.items() if "Clear:is_recursive" in values)
    assert errors == [] and cleared == ["/ros2/viz", "/ros2/viz/b"]  # ns b, then (no ns) the whole topic


def test_a_leading_slash_names_the_same_tf_frame(tmp_path):
    tf = m.TFMessage([m.TransformStamped(header=m.Header(frame_id="/odom"), child_frame_id="/base_link")])
    cloud = m.PointCloud2(header=m.Header(frame_id="/base_link"), height=1, width=1,
                          fields=[m.PointField("x", 0, 7, 1), m.PointField("y", 4, 7, 1), m.PointField("z", 8, 7, 1)],
                          point_step=12, row_step=12, data=list(struct.pack("<fff", 1, 2, 3)), is_dense=True)
    columns, errors = logged(tmp_path, [("tf2_msgs/msg/TFMessage", "ros2/tf", tf),
                                        ("sensor_msgs/msg/PointCloud2", "ros2/points", cloud)])
    transform = columns["/tf/odom/base_link"]
    assert errors == [] and (transform["Transform3D:parent_frame"], transform["Transform3D:child_frame"]) == (
        [["odom"]], [["base_link"]])
    assert columns["/ros2/points"]["CoordinateFrame:frame"] == [["base_link"]]  # in the tree tf2 names


def test_a_string_that_is_not_utf8_is_read_as_rclpy_reads_it():
    payload = b"\x00\x01\x00\x00" + struct.pack("<I", 5) + b"23\xb0C\x00"  # a Latin-1 degree sign
    assert m.decode("std_msgs/msg/String", payload).data == "23\ufffdC"
    assert m.decode("std_msgs/msg/String", m.String("ok °").serialize()).data == "ok °"


def test_a_token_whose_domain_is_not_an_ascii_number_is_a_token_error():
    key = ros2.publisher_token(0, "z", 0, 1, "/", "n", "/t", "std_msgs/msg/String", "RIHS01_0").replace("/0/", "/²/", 1)
    with pytest.raises(ros2.TokenError, match="domain id '²' is not a number"):
        ros2.parse_token(key)


def test_compressed_depth_is_refused_not_shown_as_a_broken_png(tmp_path):
    png = b"\x89PNG\r\n\x1a\n" + bytes(20)
    msg = m.CompressedImage(header=m.Header(frame_id="depth"), format="16UC1; compressedDepth png",
                            data=list(struct.pack("<iff", 0, 0.0, 0.0) + png))
    columns, errors = logged(tmp_path, [("sensor_msgs/msg/CompressedImage", "ros2/depth", msg)])
    assert "/ros2/depth" not in columns
    assert errors == ["compressed image format '16UC1; compressedDepth png': compressedDepth (a depth image behind "
                      "its transport's own header) is not shown"]


@pytest.mark.parametrize("qos,depth", [(":1:,1:,:,:,,", 1), (":1:,:,:,:,,", 42), ("2:1:1,5:,:,:,,", 5),
                                       ("::,10:,:,:,,", None), (":2:,1:,:,:,,", None)])
def test_the_tokens_qos_says_a_transient_local_publisher_and_its_depth(qos, depth):
    token = ros2.publisher_token(0, "z", 0, 1, "/", "robot_state_publisher", "/tf_static", "tf2_msgs/msg/TFMessage",
                                 "RIHS01_0", qos)
    assert ros2.parse_token(token).transient_local_depth == depth


def test_a_same_named_type_of_another_definition_is_not_decoded():
    from canbench.viewer import Viewer
    ours = ros2.type_hash("std_msgs/msg/String")
    tokens = {h: ros2.parse_token(ros2.publisher_token(0, "z", 0, 1, "/", "n", "/chatter", "std_msgs/msg/String", h))
              for h in (ours, "RIHS01_" + "ab" * 32, "TypeHashNotSupported")}
    assert {h: Viewer.decodable(e) for h, e in tokens.items()} == {
        ours: True, "RIHS01_" + "ab" * 32: False, "TypeHashNotSupported": True}


def viewed(tmp_path, samples: list[tuple]):
    """(receive ns, domain, topic, type, message[, the key's type hash: ours]) as samples of the live
    viewer's queue, logged by its logger loop into an .rrd: the viewer and the file."""
    from canbench.viewer import Sample, Viewer
    live = Viewer(None, [], True)  # type: ignore[arg-type]
    for t_ns, domain, topic, type_name, msg, *key_hash in samples:
        key = ros2.data_key(domain, topic, type_name, key_hash[0] if key_hash else ros2.type_hash(type_name))
        live.samples.put(Sample(t_ns, key, msg.serialize(), type_name))  # type: ignore[attr-defined]
    live.samples.put(None)
    path = tmp_path / "live.rrd"
    rec = rr.RecordingStream("canbench-test-live")
    rec.save(str(path))
    with rec:
        live._log_loop()
    rec.flush()
    rec.disconnect()
    return live, path


def timelines(path, component: str) -> dict[str, list[dict]]:
    """Per entity logging `component`, per chunk its time and header_stamp values (none: static)."""
    from rerun.chunk import RrdReader
    out: dict[str, list[dict]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        if any(name.startswith(component) for name in batch.schema.names):
            out.setdefault(str(chunk.entity_path), []).append(
                {n: batch.column(n).cast("int64").to_pylist() for n in ("time", "header_stamp")
                 if n in batch.schema.names})
    return out


def test_a_message_is_on_its_header_stamp_too_and_receive_time_to_the_ns(tmp_path):
    received = 1_700_000_000_250_000_001  # ns: a float of seconds is 0.24 us coarse here
    temp = m.Temperature(header=m.Header(stamp=m.Time(1_699_999_999, 900_000_000), frame_id="cabin"),
                         temperature=21.5)
    live, path = viewed(tmp_path, [(received, 0, "/cabin/temp", "sensor_msgs/msg/Temperature", temp),
                                   (received + 1, 0, "/chatter", "std_msgs/msg/String", m.String("x"))])
    assert live.logged == 2 and not live.malformed, live.malformed
    assert timelines(path, "Scalars:")["/ros2/cabin/temp/temperature"] == [
        {"time": [received], "header_stamp": [1_699_999_999_900_000_000]}]
    assert timelines(path, "TextLog:")["/ros2/chatter"] == [{"time": [received + 1]}]  # no header: not on it


def test_same_named_topics_of_two_domains_stay_apart(tmp_path):
    _, path = viewed(tmp_path, [(1_700_000_000_000_000_000 + d, d, "/chatter", "std_msgs/msg/String",
                                 m.String(f"robot {d}")) for d in (0, 7)])
    columns = read_rrd_columns(path)
    assert columns["/ros2/chatter"]["TextLog:text"] == [["robot 0"]]
    assert columns["/ros2/domain7/chatter"]["TextLog:text"] == [["robot 7"]]


@pytest.mark.parametrize("given,ok", [("0", True), ("232", True), ("233", False), ("²", False), ("-1", False)])
def test_ros_domain_option_takes_a_domain_id(given, ok):
    import argparse

    from canbench.viewer_args import ros_domain
    if ok:
        assert ros_domain(given) == int(given)
    else:
        with pytest.raises(argparse.ArgumentTypeError, match="a ROS_DOMAIN_ID is a whole number from 0 to 232"):
            ros_domain(given)


def test_the_queue_is_bounded_by_bytes_too(monkeypatch):
    from canbench import viewer
    monkeypatch.setattr(viewer, "QUEUE_BYTES", 10 << 20)
    live = viewer.Viewer(None, [], True)  # type: ignore[arg-type]
    frame = bytes(6 << 20)  # a 1080p rgb8 camera frame
    for i in range(3):
        live._enqueue(viewer.Sample(i, "0/camera/x/h", frame, "sensor_msgs/msg/Image"))
    assert (live.dropped, live.samples.qsize(), live.queued_bytes) == (2, 1, 6 << 20)  # 3 would be 18 MB
    assert len(live._batch()) == 1 and live.queued_bytes == 0  # taken: room again
    live._enqueue(viewer.Sample(3, "0/camera/x/h", frame, "sensor_msgs/msg/Image"))
    assert (live.dropped, live.samples.qsize()) == (2, 1)


def test_an_uncalibrated_camera_is_not_malformed(tmp_path):
    info = m.CameraInfo(header=m.Header(frame_id="cam"), height=480, width=640)  # K all zero, as .msg allows
    bad = m.CameraInfo(header=m.Header(frame_id="cam"), height=480, width=640, k=[-1.0, 0, 320, 0, 500, 240, 0, 0, 1])
    columns, errors = logged(tmp_path, [("sensor_msgs/msg/CameraInfo", "ros2/cam", info),
                                        ("sensor_msgs/msg/CameraInfo", "ros2/cam", bad)])
    assert errors == ["camera matrix without focal lengths: [-1.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]"]


def test_the_runs_ros2_keys_are_humbles_when_the_bridge_keys_them_so(tmp_path):
    # the ACL and the viewer's readiness wait on these keys: the bridge's own, or the run is denied and waits
    from canbench import runkeys, scenario
    path = tmp_path / "s.yaml"
    (tmp_path / "t.log").write_text("(1700000000.000100) vcan0 123#01\n")
    for humble, tail in ((False, ros2.type_hash("can_msgs/msg/Frame")), (True, "TypeHashNotSupported")):
        path.write_text("name: t\nduration_s: 5\nbuses:\n  - name: vcan0\necus:\n  - name: e\n    bus: vcan0\n"
                        f"    trace: t.log\nbridge:\n  ros2_topic: /vehicle/can\n  ros2_humble: {str(humble).lower()}\n"
                        "expect:\n  integrity: true\n")
        assert runkeys.ros2_data_keys(scenario.load(path)) == [f"0/vehicle/can/can_msgs::msg::dds_::Frame_/{tail}"]


def test_two_domains_tf_trees_stay_apart_and_transforms_are_on_their_stamps(tmp_path):
    samples = []
    for n, (domain, topic) in enumerate(((0, "/tf"), (7, "/tf"), (7, "/tf_static"))):
        stamp = m.Time(1_699_999_990 + n, 5)
        tf = m.TFMessage([m.TransformStamped(header=m.Header(stamp=stamp, frame_id="odom"), child_frame_id="base_link",
                                             transform=m.Transform(translation=m.Vector3(float(domain), 0, 0)))])
        samples.append((1_700_000_000_000_000_000 + n, domain, topic, "tf2_msgs/msg/TFMessage", tf))
    live, path = viewed(tmp_path, samples)
    assert live.logged == 3 and not live.malformed, live.malformed
    columns = read_rrd_columns(path)
    assert columns["/tf/odom/base_link"]["Transform3D:parent_frame"][0] == ["odom"]
    seven = columns["/tf/domain7/odom/base_link"]
    assert seven["Transform3D:parent_frame"][0] == ["domain7/odom"] and seven["Transform3D:child_frame"][0] == [
        "domain7/base_link"]
    stamps = {entity: sorted((chunk.get("header_stamp", ["static"])[0] for chunk in chunks), key=str)
              for entity, chunks in timelines(path, "Transform3D:translation").items()}
    assert stamps == {"/tf/odom/base_link": [1_699_999_990_000_000_005],
                      "/tf/domain7/odom/base_link": [1_699_999_991_000_000_005, "static"]}  # domain 7's tf_static


def test_a_humble_nodes_range_is_read_with_humbles_definition(tmp_path):
    """Humble's Range has no variance (Iron added it): what a Humble node sends (its rmw_zenoh keys
    say TypeHashNotSupported) is read with Humble's definition, a Jazzy node's with Jazzy's; read
    with Jazzy's, every Humble Range was malformed (4 bytes short)."""
    humble = m.RangeHumble(header=m.Header(frame_id="sonar"), min_range=0.2, max_range=4.0, range=1.25)
    jazzy = m.Range(header=m.Header(frame_id="sonar"), min_range=0.2, max_range=4.0, range=2.5, variance=0.01)
    live, path = viewed(tmp_path, [(1, 0, "/sonar", "sensor_msgs/msg/Range", humble, m.HUMBLE_HASH),
                                   (2, 0, "/sonar", "sensor_msgs/msg/Range", jazzy)])
    assert not live.malformed
    assert read_rrd_columns(path)["/ros2/sonar/range"]["Scalars:scalars"] == [[1.25], [2.5]]


def test_a_batchs_scalars_go_one_column_per_entity(tmp_path, monkeypatch):
    """/joint_states of 30 joints at a controller's rate: one rr.log per value (25-35 µs each) was
    more than the logger thread has; a batch's scalars go as one column per entity, each value on
    its message's receive time and, where it has one, its header stamp."""
    joints = [f"joint_{i}" for i in range(30)]
    samples = [(1_700_000_000_000_000_000 + k, 0, "/joint_states", "sensor_msgs/msg/JointState", m.JointState(
        header=m.Header(stamp=m.Time(1_699_999_999, k) if k % 2 else m.Time()), name=joints,
        position=[k + i / 100 for i in range(30)], velocity=[float(k)] * 30)) for k in range(50)]
    calls = {"log": 0, "send_columns": 0}
    for name in calls:
        real = getattr(rr, name)

        def counted(*args, _real=real, _name=name, **kwargs):
            calls[_name] += 1
            return _real(*args, **kwargs)
        monkeypatch.setattr(rr, name, counted)
    live, path = viewed(tmp_path, samples)
    assert live.logged == 50 and not live.malformed
    assert calls["send_columns"] <= 2 * 60 + 5 and calls["log"] < 50  # per entity and batch, not per value
    columns = read_rrd_columns(path)
    values = sorted(v for [v] in columns["/ros2/joint_states/joint_3/position"]["Scalars:scalars"])
    assert values == pytest.approx([k + 0.03 for k in range(50)])  # (stamped ones a column of their own)
    stamps = timelines(path, "Scalars:")["/ros2/joint_states/joint_3/velocity"]
    assert sorted(t for chunk in stamps for t in chunk.get("header_stamp", [])) == [
        1_699_999_999_000_000_000 + k for k in range(1, 50, 2)]  # an unstamped message is not on that timeline


def test_a_range_shows_no_point_without_a_detection_and_one_closer_than_its_minimum_at_it(tmp_path):
    """A gone obstacle leaves the screen (an empty point set, not a Clear: that would also clear the
    entity's coordinate frame, and later points would be drawn in the world's); -inf, closer than
    min_range (REP 117), is drawn at min_range but is no measured distance, unless the sensor is a
    fixed-distance ranger (min_range == max_range: Range.msg's detection at that distance)."""
    sonar = {"header": m.Header(frame_id="sonar"), "min_range": 0.2, "max_range": 4.0}
    ir = {"header": m.Header(frame_id="ir"), "min_range": 0.3, "max_range": 0.3}
    columns, errors = logged(tmp_path, [
        ("sensor_msgs/msg/Range", "ros2/park", m.Range(**sonar, range=1.5)),
        ("sensor_msgs/msg/Range", "ros2/park", m.Range(**sonar, range=math.inf)),  # the obstacle has gone
        ("sensor_msgs/msg/Range", "ros2/park", m.Range(**sonar, range=-math.inf)),  # too close to measure
        ("sensor_msgs/msg/Range", "ros2/ir", m.Range(**ir, range=-math.inf))])  # a fixed-distance detection
    assert not errors
    detection = columns["/ros2/park/detection"]
    assert "Clear:is_recursive" not in detection and detection["CoordinateFrame:frame"] == [["sonar"]]
    shown = sorted(round(p[0][0], 3) if len(p) else 0.0 for p in detection["Points3D:positions"])  # chunk order
    assert shown == [0.0, 0.2, 1.5]  # one empty: the gone obstacle
    assert columns["/ros2/park/range"]["Scalars:scalars"] == [[1.5]]  # too close is no measured distance
    assert close_to(columns["/ros2/ir/range"]["Scalars:scalars"], [[0.3]])


def close_to(a, b) -> bool:
    import numpy as np
    return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), atol=1e-6))


def test_a_fix_east_of_180_is_placed_and_one_beyond_a_pole_is_malformed_and_logs_nothing(tmp_path):
    fix = {"header": m.Header(frame_id="gnss"), "status": m.NavSatStatus(status=0)}
    columns, errors = logged(tmp_path, [
        ("sensor_msgs/msg/NavSatFix", "ros2/east", m.NavSatFix(**fix, latitude=10.0, longitude=350.0)),
        ("sensor_msgs/msg/NavSatFix", "ros2/pole", m.NavSatFix(**fix, latitude=91.0, longitude=0.0))])
    assert close_to(columns["/ros2/east"]["GeoPoints:positions"], [[[10.0, -10.0]]])
    assert errors == ["a fix at latitude 91.0: beyond a pole"]
    assert not any(entity.startswith("/ros2/pole") for entity in columns)


def test_a_pose_array_leaves_out_poses_with_nan(tmp_path):
    poses = [m.Pose(), m.Pose(position=m.Point(math.nan, 0, 0)), m.Pose(orientation=m.Quaternion(0, 0, 0, math.inf))]
    columns, errors = logged(tmp_path, [("geometry_msgs/msg/PoseArray", "ros2/particles",
                                         m.PoseArray(header=m.Header(frame_id="map"), poses=poses))])
    assert not errors
    assert close_to(columns["/ros2/particles"]["Arrows3D:origins"], [[[0, 0, 0]]])


def test_a_particle_is_an_arrow_as_long_as_its_weight_says_and_one_with_nan_is_left_out(tmp_path):
    """nav2's ParticleCloud display: 2 cm at weight 0 up to 30 cm at weight 1 (and beyond), along
    the pose's x axis; a NaN weight or pose leaves that particle out, not the cloud."""
    turned = m.Quaternion(0, 0, math.sqrt(0.5), math.sqrt(0.5))  # 90 degrees about z: along y
    particles = [m.Particle(m.Pose(position=m.Point(1, 2, 0)), 0.0), m.Particle(m.Pose(orientation=turned), 0.5),
                 m.Particle(m.Pose(), 7.0), m.Particle(m.Pose(), math.nan),
                 m.Particle(m.Pose(position=m.Point(math.inf, 0, 0)), 0.1)]
    columns, errors = logged(tmp_path, [("nav2_msgs/msg/ParticleCloud", "ros2/particle_cloud",
                                         m.ParticleCloud(header=m.Header(frame_id="map"), particles=particles))])
    assert not errors
    cloud = columns["/ros2/particle_cloud"]
    assert close_to(cloud["Arrows3D:origins"], [[[1, 2, 0], [0, 0, 0], [0, 0, 0]]])
    assert close_to(cloud["Arrows3D:vectors"], [[[0.02, 0, 0], [0, 0.16, 0], [0.3, 0, 0]]])
    assert cloud["CoordinateFrame:frame"] == [["map"]]


def test_a_namespace_with_a_slash_is_not_inside_another(tmp_path):
    # RViz's namespaces are flat: DELETEALL of 'arm' leaves 'arm/left' (MoveIt names them so)
    columns, errors = logged(tmp_path, [("visualization_msgs/msg/Marker", "ros2/viz", marker("arm", 1)),
                                        ("visualization_msgs/msg/Marker", "ros2/viz", marker("arm/left", 1)),
                                        ("visualization_msgs/msg/Marker", "ros2/viz", marker("arm", 0, action=3))])
    cleared = sorted(e for e, values in columns.items() if "Clear:is_recursive" in values)
    drawn = sorted(e for e, values in columns.items() if any(k.startswith("Cube") or k.startswith("Box")
                                                               for k in values))
    assert errors == [] and cleared == ["/ros2/viz/arm"]
    assert len(drawn) == 2 and not any(e.startswith("/ros2/viz/arm/") for e in drawn if "left" in e), drawn


def test_a_nan_intensity_greys_its_own_point_only():
    # a lidar driver marks a return without intensity NaN: the span was NaN and every point one grey
    colours = cloud_colors({"intensity": np.array([0.0, 5.0, math.nan, 10.0, math.inf], dtype=np.float32)})
    assert colours is not None and [int(c[0]) for c in colours] == [0, 127, 0, 255, 0]
    assert [int(c[0]) for c in cloud_colors({"intensity": np.array([math.nan, 3.0])})] == [0, 255]
