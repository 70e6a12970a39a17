"""A recording's definitions of its types (an MCAP's ros2msg schemas, as rosbag2 writes them: the
.msg texts with comments, constants, defaults and names of the type's own package) against the
ones the viewer decodes: the same definition agrees however it is written; another one (an older
distribution's Marker, Humble's Range) is said, naming the field, and its messages are not
decoded into garbage or counted malformed one by one."""
from __future__ import annotations

import subprocess
import sys

import pytest
from mcap.writer import CompressionType, Writer

from canbench import ros2, ros2_msgs

pytestmark = pytest.mark.unit

# geometry_msgs/PoseArray as rosbag2 stores it (the .msg files of Jazzy's common_interfaces, trimmed comments)
POSE_ARRAY_AS_RECORDED = """# An array of poses with a header for global reference.

std_msgs/Header header

Pose[] poses
================================================================================
MSG: geometry_msgs/Pose
# A representation of pose in free space, composed of position and orientation.

Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
# This contains the position of a point in free space
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
# This represents an orientation in free space in quaternion form.

float64 x 0
float64 y 0
float64 z 0
float64 w 1
================================================================================
MSG: std_msgs/Header
# Standard metadata for higher-level stamped data types.
builtin_interfaces/Time stamp  # the time
string frame_id
uint8 UNUSED_CONSTANT=3  # constants are not fields
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def test_the_same_definition_agrees_however_it_is_written():
    assert ros2.definition_difference("geometry_msgs/msg/PoseArray", POSE_ARRAY_AS_RECORDED) is None
    for ros_type in ros2.MESSAGE_TYPES:
        assert ros2.definition_difference(ros_type, ros2.msg_definition(ros_type)) is None, ros_type


def test_jazzys_definitions_agree_and_older_ones_are_named():
    from rosbags.typesys import Stores, get_typestore
    stores = {name: get_typestore(store) for name, store in
              (("jazzy", Stores.ROS2_JAZZY), ("humble", Stores.ROS2_HUMBLE), ("foxy", Stores.ROS2_FOXY))}

    def differences(name: str) -> dict[str, str | None]:
        store = stores[name]
        return {t: d for t in ros2.MESSAGE_TYPES if t in store.fielddefs
                and (d := ros2.definition_difference(t, store.generate_msgdef(t, ros_version=2)[0]))}

    assert differences("jazzy") == {}
    assert differences("humble") == {"sensor_msgs/msg/Range": "sensor_msgs/Range: 6 fields there, 7 here"}
    for ros_type, variant in ros2_msgs.HUMBLE_VARIANTS.items():  # what a Humble node or bag is read with
        humble_text = stores["humble"].generate_msgdef(ros_type, ros_version=2)[0]
        assert ros2.definition_difference(ros_type, humble_text, variant) is None
    assert differences("foxy")["visualization_msgs/msg/MarkerArray"] == (
        "visualization_msgs/Marker: field 13 is 'string text' there, 'string texture_resource' here")


def test_a_changed_field_type_is_named():
    changed = POSE_ARRAY_AS_RECORDED.replace("float64 w 1", "float32 w 1")
    assert ros2.definition_difference("geometry_msgs/msg/PoseArray", changed) == (
        "geometry_msgs/Quaternion: field 4 is 'float32 w' there, 'float64 w' here")


def test_the_viewer_decodes_the_channels_of_its_definition_only(tmp_path):
    """A channel of another definition is said and skipped; one of Humble's Range (recorded by a
    Humble rosbag2) is read with Humble's definition."""
    pytest.importorskip("rerun", reason="the viewer needs rerun-sdk")
    path = tmp_path / "bag.mcap"
    pose_array = ros2_msgs.PoseArray(header=ros2_msgs.Header(frame_id="map"), poses=[ros2_msgs.Pose()])
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        ours = w.register_schema("geometry_msgs/msg/PoseArray", "ros2msg", POSE_ARRAY_AS_RECORDED.encode())
        other = w.register_schema("geometry_msgs/msg/PoseArray", "ros2msg",
                                  POSE_ARRAY_AS_RECORDED.replace("float64 w 1", "float32 w 1").encode())
        channels = [w.register_channel("/particlecloud", "cdr", ours), w.register_channel("/legacy", "cdr", other)]
        for i in range(3):
            for channel in channels:
                w.add_message(channel, log_time=i, publish_time=i, sequence=i, data=pose_array.serialize())
        humble = w.register_schema("sensor_msgs/msg/Range", "ros2msg", ros2.msg_definition(
            "sensor_msgs/msg/Range", ros2_msgs.RangeHumble).encode())
        sonar = ros2_msgs.RangeHumble(header=ros2_msgs.Header(frame_id="sonar"), max_range=4.0, range=1.25)
        w.add_message(w.register_channel("/sonar", "cdr", humble), log_time=5, publish_time=5, sequence=0,
                      data=sonar.serialize())
        w.finish()
    rrd = tmp_path / "bag.rrd"
    out = subprocess.run([sys.executable, "-m", "canbench.cli", "view", str(path), "--save", str(rrd)],
                         capture_output=True, text=True, check=True, timeout=120).stdout
    assert "4 messages from" in out and "0 malformed, 3 not decoded" in out
    from canbench.viewer import read_rrd_columns
    columns = read_rrd_columns(rrd)
    assert columns["/discovery/errors"]["TextLog:text"] == [[
        "/legacy: recorded with another definition of geometry_msgs/msg/PoseArray (geometry_msgs/Quaternion: "
        "field 4 is 'float32 w' there, 'float64 w' here): not decoded"]]
    assert len(columns["/particlecloud"]["Arrows3D:vectors"]) == 3 and "/legacy" not in columns
    assert columns["/sonar/range"]["Scalars:scalars"] == [[1.25]]


def float64_recording(path, count: int, compression: CompressionType = CompressionType.ZSTD) -> None:
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=4096, compression=compression)  # chunks of about a hundred messages
        w.start(profile="ros2", library="test")
        schema = w.register_schema("std_msgs/msg/Float64", "ros2msg",
                                   ros2.msg_definition("std_msgs/msg/Float64").encode())
        channel = w.register_channel("/speed", "cdr", schema)
        for i in range(count):
            w.add_message(channel, log_time=1_700_000_000_000_000_000 + i * 10_000_000, publish_time=0, sequence=i,
                          data=ros2_msgs.Float64(float(i)).serialize())
        w.finish()


def test_a_cut_recording_is_shown_up_to_the_cut_and_said(tmp_path):
    """A recording without its end (power lost in the car, the recorder killed) had no index: the
    viewer stopped with mcap's EndOfFile traceback and showed nothing."""
    pytest.importorskip("rerun", reason="the viewer needs rerun-sdk")
    path, rrd = tmp_path / "drive.mcap", tmp_path / "drive.rrd"
    float64_recording(path, 5000)
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size * 2 // 3)
    run = subprocess.run([sys.executable, "-m", "canbench.cli", "view", str(path), "--save", str(rrd)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1, run.stderr[-2000:]  # shown, but not the whole recording
    assert "INCOMPLETE: the recording is cut or damaged (a record ends past the file's end, after" in run.stderr
    from canbench.viewer import read_rrd_columns
    columns = read_rrd_columns(rrd)
    shown = sum(len(v) for v in columns["/speed"]["Scalars:scalars"])
    assert 1000 < shown < 5000  # every message before the cut
    assert "the recording is cut or damaged" in columns["/discovery/errors"]["TextLog:text"][-1][0]


def test_what_was_read_is_sent_however_the_reading_ends(tmp_path, monkeypatch):
    """Scalars wait to be sent together: an interrupted reading (Ctrl-C) still sends those read."""
    rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk")
    from canbench import recording
    from canbench.viewer import read_rrd_columns
    from canbench.viewer_types import Context, registry
    path, rrd = tmp_path / "drive.mcap", tmp_path / "drive.rrd"
    float64_recording(path, 50)
    monkeypatch.setattr(registry, "FLUSH_AFTER_S", 3600.0)  # nothing is due while reading
    real = recording.recorded_messages

    def interrupted(f, path):
        for i, item in enumerate(real(f, path)):
            if i == 30:
                raise KeyboardInterrupt
            yield item
    monkeypatch.setattr(recording, "recorded_messages", interrupted)
    rec = rr.RecordingStream("canbench-test-interrupted")
    rec.save(str(rrd))
    with rec, pytest.raises(KeyboardInterrupt):
        recording.view_mcap(path, Context())
    rec.flush()
    rec.disconnect()
    assert sum(len(v) for v in read_rrd_columns(rrd)["/speed"]["Scalars:scalars"]) == 30


def test_scalars_are_due_after_a_while_or_many_values(monkeypatch):
    from canbench.viewer_types import registry
    now = [100.0]
    monkeypatch.setattr(registry.time, "monotonic", lambda: now[0])
    columns = registry.ScalarColumns()
    assert not columns.due()  # nothing to send
    columns.add("/a", 1, None, 1.0)
    assert not columns.due()  # a value per sample would be sent as a one-row column: worse than rr.log
    now[0] += registry.FLUSH_AFTER_S * 1.01
    assert columns.due()
    columns.series.clear()
    columns.pending.sent()
    for i in range(registry.FLUSH_VALUES):
        columns.add("/a", i, None, 1.0)
    assert columns.due()


def test_a_damaged_chunk_is_said_not_shown_with_wrong_values(tmp_path):
    """A flipped bit in a message of an indexed recording (uncompressed: nothing but the chunk's
    CRC can tell): the CRC is checked (mcap's default is not to), so the reading stops there and
    says so, rather than show 1500.0 as another value."""
    pytest.importorskip("rerun", reason="the viewer needs rerun-sdk")
    path = tmp_path / "drive.mcap"
    float64_recording(path, 3000, CompressionType.NONE)
    data = bytearray(path.read_bytes())
    at = data.index(ros2_msgs.Float64(1500.0).serialize()) + 6  # a byte of the value, not of a length
    data[at] ^= 0x01
    path.write_bytes(bytes(data))
    run = subprocess.run([sys.executable, "-m", "canbench.cli", "view", str(path), "--save", str(tmp_path / "d.rrd")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "INCOMPLETE: the recording is cut or damaged" in run.stderr, run.stderr[-2000:]


@pytest.mark.parametrize("content", [b"", b"\x89MCAP", b"(1700000000.000100) can0 123#01\n"])
def test_a_file_that_is_no_mcap_is_refused_in_one_line(tmp_path, content):
    path = tmp_path / "drive.mcap"
    path.write_bytes(content)
    run = subprocess.run([sys.executable, "-m", "canbench.cli", "view", str(path), "--save", str(tmp_path / "d.rrd")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and run.stderr.strip().endswith(
        f"{path}: not an MCAP file (canbench view reads MCAP recordings; a CAN trace goes through canbench "
        "summarise or a scenario)"), run.stderr[-2000:]


def test_a_schema_text_that_cannot_be_read_is_another_definition():
    assert ros2.definition_difference("std_msgs/msg/Float64", "float64 =1\n") == (
        "std_msgs/Float64: 0 fields there, 1 here")
