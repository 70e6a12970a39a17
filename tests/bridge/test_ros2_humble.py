"""The bridge's ROS 2 output for Humble (--ros2-humble 1): Humble's rmw_zenoh has no type
hashes and puts TypeHashNotSupported in their place, in data keys and liveliness tokens, and its
subscribers match the key exactly, so a RIHS01 key is never seen by a Humble node. Here a
subscriber on Humble's exact key receives the bus's frames as can_msgs/msg/Frame, and the
publisher's token says TypeHashNotSupported. Readiness: the bridge's token; then a frame
until the subscriber has one. The ROS 2 tokens come before the bridge's own, so a client that
waited for the bridge's token finds the ROS 2 topic."""
from __future__ import annotations

import queue
import threading

from conftest import wait_for, zenoh_session

from canbench import ros2, ros2_msgs

HUMBLE_KEY = "0/vehicle/can/can_msgs::msg::dds_::Frame_/TypeHashNotSupported"


def test_humble_subscribers_receive_the_frames(bus, bridge, router, session):
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--ros2-topic", "/vehicle/can", "--ros2-humble", "1")
    bridge.wait_ready(session)
    tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
    publishers = [ros2.parse_token(t) for t in tokens if "/MP/" in t]
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


def test_ros2_tokens_come_before_the_bridge_token(bus, bridge, router, session):
    """In the order the router hands the bridge's liveliness tokens to a subscriber, the ROS 2
    node's and publisher's precede the bridge's: a liveliness query made once the bridge's token
    is seen then always finds the topic (with them declared after, it raced). Readiness: a probe
    token from a second session reaches the subscribers, so the router knows their interest."""
    seen: list[str] = []
    lock = threading.Lock()

    def note(sample):
        with lock:
            seen.append(str(sample.key_expr))
    subs = [session.liveliness().declare_subscriber(k, note) for k in ("@ros2_lv/0/**", "vehicle/can/bridges/**")]
    probe_session = zenoh_session(router.endpoint)
    try:
        probe = probe_session.liveliness().declare_token("vehicle/can/bridges/probe/ready")
        wait_for(lambda: "vehicle/can/bridges/probe/ready" in seen, "the liveliness subscribers at the router")
        probe.undeclare()
        bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--ros2-topic", "/vehicle/can")
        bridge.wait_ready(session)
        wait_for(lambda: any(k.startswith("vehicle/can/bridges/zenoh-node/") for k in seen), "the bridge's token")
    finally:
        probe_session.close()
        for sub in subs:
            sub.undeclare()
    with lock:
        order = [k for k in seen if "probe" not in k]
    bridge_at = next(i for i, k in enumerate(order) if k.startswith("vehicle/can/bridges/zenoh-node/"))
    ros = [i for i, k in enumerate(order) if k.startswith("@ros2_lv/")]
    assert len(ros) == 2 and max(ros) < bridge_at, order  # the node's token and the publisher's
