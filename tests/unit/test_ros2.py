"""rmw_zenoh conventions against published examples: liveliness tokens from
rmw_zenoh's design document (incl. namespaces and mangling), DDS type names,
data keys, REP-2011 type hashes against the hashes ROS 2 publishes for
std_msgs/String and sensor_msgs/Imu, and CDR against known bytes."""
from __future__ import annotations

import pytest

from canbench import ros2

pytestmark = pytest.mark.unit

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
IMU_HASH = "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
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


def test_cdr_known_bytes_and_round_trips():
    assert ros2.String("hello").serialize().hex() == "000100000600000068656c6c6f00"
    frame = ros2.CanFrame(id=0x123, dlc=2, data=bytes([1, 2, 0, 0, 0, 0, 0, 0]))
    # encapsulation | stamp 0,0 | frame_id "" (len 1 + NUL, pad 3) | id | rtr ext err | dlc | data
    assert frame.serialize().hex() == ("00010000" "00000000" "00000000" "01000000" "00" "000000" "23010000"
                                       "000000" "02" "0102000000000000")
    for cls in ros2.MESSAGE_TYPES.values():
        msg = cls()
        assert cls.deserialize(msg.serialize()) == msg
