"""The bridge's ROS 2 output for Humble (--ros2-humble 1): Humble's rmw_zenoh has no type
hashes and puts TypeHashNotSupported in their place, in data keys and liveliness tokens, and its
subscribers match the key exactly, so a RIHS01 key is never seen by a Humble node. Here a
subscriber on Humble's exact key receives the bus's frames as can_msgs/msg/Frame, and the
publisher's token says TypeHashNotSupported. Readiness: the bridge's token; then a frame
until the subscriber has one. The ROS 2 publisher's token is waited for on its own: Zenoh does
not promise another client sees a session's tokens in the order they were declared."""
from __future__ import annotations

import queue

from conftest import wait_for

from canbench import ros2, ros2_msgs

HUMBLE_KEY = "0/vehicle/can/can_msgs::msg::dds_::Frame_/TypeHashNotSupported"


def test_humble_subscribers_receive_the_frames(bus, bridge, router, session):
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--ros2-topic", "/vehicle/can", "--ros2-humble", "1")
    bridge.wait_ready(session)

    def ros2_publishers():
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
        return [ros2.parse_token(t) for t in tokens if "/MP/" in t]
    publishers = wait_for(ros2_publishers, "the bridge's ROS 2 publisher token")
    assert [(p.topic, p.type_name, p.type_hash) for p in publishers] == [
        ("/vehicle/can", "can_msgs/msg/Frame", "TypeHashNotSupported")]
    assert publishers[0].data_key == HUMBLE_KEY
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber(HUMBLE_KEY, lambda s: got.put(s.payload.to_bytes()))
    try:
        # the subscription reaches the router a moment after its declaration: a frame until one arrives
        payload = None
        for _ in range(40):
            bus.run(["cansend", "vcan0", "123#DEADBEEF"])
            try:
                payload = got.get(timeout=0.25)
                break
            except queue.Empty:
                continue
        assert payload is not None, "no frame on Humble's key in 10 s"
        frame = ros2_msgs.decode("can_msgs/msg/Frame", payload)
    finally:
        sub.undeclare()
    assert (frame.id, frame.dlc, bytes(frame.data[:4])) == (0x123, 4, bytes.fromhex("DEADBEEF"))
