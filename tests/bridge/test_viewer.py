"""The viewer against the real network: zenohd, the bridge on the bus (with
its ROS 2 output on /vehicle/can), and a ROS 2 publisher speaking rmw_zenoh's
conventions (liveliness token, data key with the RIHS01 hash, CDR).
`canbench view --save` records what it discovers; the test reads the .rrd
back with Rerun's own reader and finds the CAN frames (raw and DBC-decoded),
the same frames through the bridge's can_msgs/msg/Frame topic (discovered by
@ros2_lv, decoded from CDR), the ROS 2 scalars, and the unknown type listed,
not fatal. Readiness: the viewer's liveliness token and stats queryable."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
import zenoh
from conftest import REPO, wait_for

from canbench import ros2, ros2_msgs

rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

TEMPERATURES = [20.5, 21.0, 21.5]
ENGINE_SPEED_FRAME = "0C0#C1E803000000000B"  # EngineSpeed 0x03E8 * 0.25 = 250 rpm


def viewer_stats(session) -> dict | None:
    replies = [r for r in session.get("canbench/viewers/*/stats") if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


def test_viewer_records_bridge_frames_and_ros2_topics(bus, bridge, router, session, tmp_path):
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--ros2-topic", "/vehicle/can")
    bridge.wait_ready(session)
    zid = str(session.info.zid())
    temp_hash = ros2.type_hash("sensor_msgs/msg/Temperature")
    tokens = [session.liveliness().declare_token(ros2.node_token(0, zid, 0, "/cabin", "climate")),
              session.liveliness().declare_token(ros2.publisher_token(
                  0, zid, 0, 1, "/cabin", "climate", "/cabin/temperature", "sensor_msgs/msg/Temperature", temp_hash)),
              session.liveliness().declare_token(ros2.publisher_token(
                  0, zid, 0, 2, "/", "arm", "/arm/trajectory", "trajectory_msgs/msg/JointTrajectory",
                  "RIHS01_" + "0" * 64))]
    rrd = tmp_path / "view.rrd"
    viewer = subprocess.Popen([sys.executable, "-m", "canbench.cli", "view", "--zenoh-connect", router.endpoint,
                               "--auto-subscribe", "--dbc", str(REPO / "scenarios" / "dbc" / "powertrain.dbc"),
                               "--save", str(rrd), "--duration", "120"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        key = ros2.data_key(0, "/cabin/temperature", "sensor_msgs/msg/Temperature", temp_hash)
        can_key = ros2.data_key(0, "/vehicle/can", "can_msgs/msg/Frame", ros2.type_hash("can_msgs/msg/Frame"))
        wait_for(lambda: (s := viewer_stats(session)) and {key, can_key} <= set(s["subscriptions"]) and s["bridges"],
                 "the viewer subscribed to the discovered topics and seeing the bridge")
        publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        for value in TEMPERATURES:
            publisher.put(ros2_msgs.Temperature(temperature=value).serialize())
        for frame in (ENGINE_SPEED_FRAME, "18DAF110#R", "7FF#"):
            bus.run(["cansend", "vcan0", frame])
        wait_for(lambda: viewer_stats(session)["logged"] >= len(TEMPERATURES) + 2 * 3, "the viewer logging it all")
        viewer.send_signal(subprocess.signal.SIGINT)
        out, err = viewer.communicate(timeout=30)
    finally:
        if viewer.poll() is None:
            viewer.kill()
        for t in tokens:
            t.undeclare()
    assert viewer.returncode == 0, err[-3000:]
    from canbench.viewer import read_rrd
    logged = read_rrd(rrd)
    assert logged["/ros2/cabin/temperature/temperature"] == TEMPERATURES
    assert logged["/can/rx/vcan0/0C0/raw"] == ["0C0#C1E803000000000B"]
    assert logged["/can/rx/vcan0/0C0/EngineSpeed"] == [250.0]
    assert "/can/rx/vcan0/18DAF110/raw" in logged and "/can/rx/vcan0/7FF/raw" in logged
    # the bridge's ROS 2 output, found through @ros2_lv and decoded from CDR: the same frames
    assert logged["/ros2/vehicle/can/0C0/raw"] == ["0C0#C1E803000000000B"]
    assert logged["/ros2/vehicle/can/0C0/EngineSpeed"] == [250.0]
    assert logged["/ros2/vehicle/can/18DAF110/raw"] == ["18DAF110#R"]
    assert "/vehicle/can [can_msgs/msg/Frame]" in " ".join(logged["/discovery/ros2"])
    discovery = " ".join(logged["/discovery/ros2"])
    assert "/cabin/temperature [sensor_msgs/msg/Temperature]" in discovery
    assert "/arm/trajectory [trajectory_msgs/msg/JointTrajectory] (no logger)" in discovery
    assert logged["/discovery/unsupported"] == ["trajectory_msgs/msg/JointTrajectory (first seen on /arm/trajectory)"]
    assert any("vehicle/can/bridges/" in line for line in logged["/discovery/bridges"])
