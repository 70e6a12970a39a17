"""rmw_zenoh conventions against published examples: liveliness tokens from
rmw_zenoh's design document (incl. namespaces and mangling), DDS type names,
data keys, REP-2011 type hashes against the hashes ROS 2 publishes for
std_msgs/String, sensor_msgs/Imu, Image, CameraInfo and std_msgs/Header, CDR
against known bytes (incl. an Image vector made with rosbags, another CDR
implementation), and the .msg texts MCAP's ros2msg schemas carry, parsed by
mcap-ros2-support."""
from __future__ import annotations

import math

import numpy as np
import pytest

from canbench import ros2, ros2_msgs

pytestmark = pytest.mark.unit

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
PUBLISHED_HASHES = {  # as `ros2 topic info -v` shows them (Jazzy): field order, types, nesting of each
    "std_msgs/msg/Header": "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "builtin_interfaces/msg/Time": "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "sensor_msgs/msg/Image": "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "sensor_msgs/msg/CameraInfo": "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    "sensor_msgs/msg/RegionOfInterest": "RIHS01_ad16bcba5f9131dcdba6fbded19f726f5440e3c513b4fb586dd3027eeed8abb1",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "sensor_msgs/msg/PointCloud2": "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    "sensor_msgs/msg/LaserScan": "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    "sensor_msgs/msg/CompressedImage": "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
    "visualization_msgs/msg/Marker": "RIHS01_45b13ccf791f225962bf74e746f9644518855d783a6f42ba0cc14fde2b4f3ce0",
    "visualization_msgs/msg/MarkerArray": "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "nav_msgs/msg/OccupancyGrid": "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "nav_msgs/msg/Path": "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
}
# verbatim from rmw_zenoh docs/design.md
PUB = ("@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
       f"{STRING_HASH}/::,7:,:,:,,")
NODE = "@ros2_lv/0/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"


def test_publisher_token_fields():
    e = ros2.parse_token(PUB)
    assert (e.domain_id, e.kind, e.node, e.topic, e.type_name, e.type_hash, e.qos) == (
        0, "MP", "talker", "/chatter", "std_msgs/msg/String", STRING_HASH, "::,7:,:,:,,")
    assert e.data_key == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"


def test_node_token_and_mangled_namespace():
    assert ros2.parse_token(NODE).kind == "NN" and ros2.parse_token(NODE).topic == ""
    e = ros2.parse_token("@ros2_lv/42/z/3/7/MS/%/%robot1%arm/ctl/%robot1%arm%imu/sensor_msgs::msg::dds_::Imu_/"
                         f"{IMU_HASH}/::,10:,:,:,,")
    assert (e.domain_id, e.namespace, e.topic, e.type_name) == (42, "/robot1/arm", "/robot1/arm/imu",
                                                                "sensor_msgs/msg/Imu")
    assert e.data_key == f"42/robot1/arm/imu/sensor_msgs::msg::dds_::Imu_/{IMU_HASH}"


@pytest.mark.parametrize("bad", ["@ros2_lv/0/z/n/i/XX/%/%/node", "@ros2_lv/zero/z/n/i/NN/%/%/node",
                                 "@ros2_lv/0/z/n/i/NN/%", "vehicle/can/bridges/x/vcan0/client",
                                 "@ros2_lv/0/z/n/i/MP/%/%/n/%t/not_a_dds_type/h/q"])
def test_malformed_tokens_are_refused(bad):
    with pytest.raises(ros2.TokenError):
        ros2.parse_token(bad)


def test_own_tokens_round_trip():
    token = ros2.publisher_token(0, "ab" * 16, 0, 1, "/", "zenoh_node", "/vehicle/can0", "can_msgs/msg/Frame",
                                 ros2.type_hash("can_msgs/msg/Frame"))
    e = ros2.parse_token(token)
    assert (e.topic, e.type_name, e.node) == ("/vehicle/can0", "can_msgs/msg/Frame", "zenoh_node")


def test_type_hashes_match_ros2():
    assert ros2.type_hash("std_msgs/msg/String") == STRING_HASH
    assert ros2.type_hash("sensor_msgs/msg/Imu") == IMU_HASH  # nested types, fixed arrays
    assert ros2.type_hash("can_msgs/msg/Frame").startswith("RIHS01_")
    for ros_type, published in PUBLISHED_HASHES.items():  # sequences, nested fixed arrays, a nested struct
        assert ros2.type_hash(ros_type) == published, ros_type


def test_every_type_is_ros2_jazzys_definition():
    """Against rosbags' store of ROS 2 Jazzy's message definitions (generated from the .msg files)
    and its own RIHS01 hashes: each type's fields in order, with their types, and its hash, for
    every type the viewer decodes (can_msgs is not a core package: the bridge's own)."""
    from rosbags.typesys import Stores, get_typestore
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    ours = sorted(t for t in ros2.MESSAGE_TYPES if not t.startswith(("can_msgs/", "nav2_msgs/")))
    assert [t for t in ours if t not in jazzy.fielddefs] == []
    for ros_type in ours:
        assert [f["name"] for f in ros2.fields(ros_type)] == [name for name, _ in jazzy.fielddefs[ros_type][1]]
        assert ros2.type_hash(ros_type) == jazzy.hash_rihs01(ros_type), ros_type


# nav2_msgs' definitions (ros-navigation/navigation2, nav2_msgs/msg/*.msg; comments left out)
NAV2_MSGS = {"nav2_msgs/msg/Particle": "geometry_msgs/Pose pose\nfloat64 weight\n",
             "nav2_msgs/msg/ParticleCloud": "std_msgs/Header header\nParticle[] particles\n"}


def test_every_nav2_type_is_nav2s_definition():
    """nav2_msgs is no core package: its .msg files, registered beside Jazzy's, give the fields and
    the RIHS01 hash that amcl's rmw_zenoh keys carry."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    for name, text in NAV2_MSGS.items():
        store.register(get_types_from_msg(text, name))
    ours = sorted(t for t in ros2.MESSAGE_TYPES if t.startswith("nav2_msgs/"))
    assert ours == sorted(NAV2_MSGS)
    for ros_type in ours:
        assert [f["name"] for f in ros2.fields(ros_type)] == [name for name, _ in store.fielddefs[ros_type][1]]
        assert ros2.type_hash(ros_type) == store.hash_rihs01(ros_type), ros_type


def test_cdr_known_bytes_and_round_trips():
    assert ros2_msgs.String("hello").serialize().hex() == "000100000600000068656c6c6f00"
    image = ros2_msgs.Image(header=ros2_msgs.Header(stamp=ros2_msgs.Time(1, 2), frame_id="cam"), height=1, width=2,
                            encoding="rgb8", step=6, data=[1, 2, 3, 4, 5, 6])
    assert image.serialize().hex() == ("0001000001000000020000000400000063616d0001000000020000000500000072676238"
                                       "000000000600000006000000010203040506")
    frame = ros2_msgs.CanFrame(id=0x123, dlc=2, data=bytes([1, 2, 0, 0, 0, 0, 0, 0]))
    # encapsulation | stamp 0,0 | frame_id "" (len 1 + NUL, pad 3) | id | rtr ext err | dlc | data
    assert frame.serialize().hex() == ("00010000" "00000000" "00000000" "01000000" "00" "000000" "23010000"
                                       "000000" "02" "0102000000000000")
    for cls in ros2.MESSAGE_TYPES.values():
        msg = cls()
        assert cls.deserialize(msg.serialize()) == msg


def test_decode_refuses_what_is_not_ros2_cdr():
    good = ros2_msgs.String("x").serialize()
    assert ros2_msgs.decode("std_msgs/msg/String", good).data == "x"
    for bad, why in [(b"", "empty payload"), (b"\x00\x03\x00\x00" + good[4:], "encapsulation"),
                     (good[:6], "malformed CDR"), (good[:4] + b"\xff\xff\xff\x7f" + good[8:], "malformed CDR")]:
        with pytest.raises(ros2_msgs.CdrError, match=why):
            ros2_msgs.decode("std_msgs/msg/String", bad)



def test_byte_sequences_are_read_as_one_slice_and_checked_against_the_payload():
    """An image's data comes back as bytes (one slice of the payload, not a list of ints built one
    by one), equal to what was sent; a length past the payload is malformed, not a short image."""
    pixels = bytes(range(256)) * 12  # 32 x 32 rgb8
    image = ros2_msgs.Image(height=32, width=32, encoding="rgb8", step=96, data=pixels)
    payload = image.serialize()
    decoded = ros2_msgs.decode("sensor_msgs/msg/Image", payload)
    assert type(decoded.data) is bytes and decoded.data == pixels and decoded == image
    as_list = ros2_msgs.Image(height=32, width=32, encoding="rgb8", step=96, data=list(pixels))
    assert as_list.serialize() == payload  # a list of ints is still written as before
    as_array = np.frombuffer(pixels, np.uint8).reshape(32, 32, 3)  # len() counts rows: the length is its bytes
    for buffer in (as_array, memoryview(as_array), bytearray(pixels)):
        assert ros2_msgs.Image(height=32, width=32, encoding="rgb8", step=96, data=buffer).serialize() == payload
    for bad in (payload[:-1], payload[:-len(pixels) - 4] + (2**32 - 1).to_bytes(4, "little") + pixels):
        with pytest.raises(ros2_msgs.CdrError, match="ends past the payload"):
            ros2_msgs.decode("sensor_msgs/msg/Image", bad)
    cells = [-1, 0, 100, 50, -128, 127]  # a map's int8 cells: one slice too, signed
    grid = ros2_msgs.decode("nav_msgs/msg/OccupancyGrid", ros2_msgs.OccupancyGrid(data=cells).serialize())
    assert list(grid.data) == cells and np.asarray(grid.data).dtype == np.int8

@pytest.mark.parametrize("ros_type", sorted(ros2.MESSAGE_TYPES))
def test_msg_definitions_decode_our_cdr(ros_type):
    """The ros2msg schema text of every type, parsed by the MCAP ROS 2 decoder, reads our CDR."""
    mcap_ros2 = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (pip install -e '.[viewer]')")
    from mcap.records import Schema
    schema = Schema(id=1, name=ros_type, encoding="ros2msg", data=ros2.msg_definition(ros_type).encode())
    decoded = mcap_ros2.DecoderFactory().decoder_for("cdr", schema)(ros2.MESSAGE_TYPES[ros_type]().serialize())
    assert [f for f in ros2.fields(ros_type)][0]["name"] in dir(decoded)


def _primitives(obj) -> dict:
    """Top-level numbers and strings of a message (ours or mcap_ros2's), nested one level."""
    out = {}
    for name in ros2.fields(type(obj).__idl_typename__) if hasattr(obj, "__idl_typename__") else []:
        value = getattr(obj, name["name"])
        out[name["name"]] = value if isinstance(value, int | float | str) else None
    return out


def test_another_decoder_reads_the_catalogue_the_same():
    """Every catalogue message, decoded by mcap-ros2-support from its ros2msg text: the same
    top-level values and the same header (field order and alignment agree)."""
    mcap_ros2 = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (pip install -e '.[viewer]')")
    from mcap.records import Schema
    from ros2_catalogue import CASES
    for case in CASES:
        schema = Schema(id=1, name=case.type_name, encoding="ros2msg",
                        data=ros2.msg_definition(case.type_name).encode())
        theirs = mcap_ros2.DecoderFactory().decoder_for("cdr", schema)(case.msg.serialize())
        ours = _primitives(case.msg)
        for name, value in ours.items():
            if value is not None:
                got = getattr(theirs, name)
                both_nan = isinstance(value, float) and math.isnan(value) and math.isnan(got)
                assert got == value or both_nan or (isinstance(value, float) and abs(got - value) < 1e-6), (
                    case.topic, name)
        if hasattr(case.msg, "header"):
            assert theirs.header.frame_id == case.msg.header.frame_id, case.topic
            assert theirs.header.stamp.nanosec == case.msg.header.stamp.nanosec, case.topic
        for seq in ("data", "ranges", "transforms", "markers", "poses"):  # sequences: same length
            if isinstance(getattr(case.msg, seq, None), list | bytes):
                assert len(getattr(theirs, seq)) == len(getattr(case.msg, seq)), (case.topic, seq)
