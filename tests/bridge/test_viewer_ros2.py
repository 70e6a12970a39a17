"""The viewer against ROS 2 nodes as rmw_zenoh runs them (canbench.ros2.Node:
liveliness tokens, data keys <domain>/<topic>/<dds type>/<RIHS01 hash>, CDR
from the .msg definitions, rmw's attachment), through a zenohd on loopback:
every type of tests/ros2_catalogue.py with its values read back from the
.rrd, malformed CDR of every type counted and skipped, -t selecting exactly
its topics in peer mode (no router: the viewer connects to the publisher's
peer), and a topic whose publisher goes away unsubscribed.
Readiness: the viewer's liveliness token and its stats queryable."""
from __future__ import annotations

import json
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh
from conftest import Router, wait_for, zenoh_session
from ros2_catalogue import CASES, malformed_variants

from canbench import ros2
from canbench.rig import free_port
from canbench.runkeys import base_config

URDF = Path(__file__).parents[1] / "data" / "viewer" / "car.urdf"
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")
from canbench.viewer import read_rrd_columns  # noqa: E402


def viewer_stats(session) -> dict | None:
    replies = [r for r in session.get("canbench/viewers/*/stats") if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


@contextmanager
def viewer(session, rrd: Path, *args: str):
    """canbench view --save rrd, ready (its stats answer) on entry, stopped like Ctrl-C on exit."""
    proc = subprocess.Popen([sys.executable, "-m", "canbench.cli", "view", "--save", str(rrd), "--duration", "120",
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: proc.poll() is not None or viewer_stats(session), "the viewer's stats queryable", timeout=30)
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        yield proc
        proc.send_signal(subprocess.signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def listening_peer(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@pytest.fixture
def lone_router(tmp_path):
    """zenohd on loopback, no CAN bus: these tests need none."""
    r = Router(tmp_path)
    r.start()
    yield r
    r.stop()


def subscribed(session, keys: set[str]) -> bool:
    s = viewer_stats(session)
    return bool(s) and keys <= set(s["subscriptions"])


def test_every_type_logged_with_its_values_and_malformed_cdr_skipped(lone_router, tmp_path):
    session = zenoh_session(lone_router.endpoint)
    node = ros2.Node(session, "catalogue", "/bench")
    rrd = tmp_path / "types.rrd"
    try:
        with viewer(session, rrd, "--zenoh-connect", lone_router.endpoint, "--auto-subscribe"):
            pubs = [node.publisher(c.topic, c.type_name) for c in CASES]
            wait_for(lambda: subscribed(session, {p.key for p in pubs}), "the viewer subscribed to every topic")
            bad: dict[str, int] = {}
            for case, pub in zip(CASES, pubs, strict=True):
                pub.put(case.msg)
            for case, pub in zip(CASES, pubs, strict=True):
                variants = malformed_variants(case.msg.serialize())[:8]  # truncations, wrong encapsulations
                for payload in variants:
                    pub.put(payload)
                bad[case.topic] = len(variants)
            total = len(CASES) + sum(bad.values())
            wait_for(lambda: viewer_stats(session)["logged"] >= total, f"the viewer logging {total} samples")
            stats = viewer_stats(session)
    finally:
        node.close()
        session.close()
    assert stats["dropped"] == 0
    assert stats["malformed"] == bad  # every malformed sample counted against its topic, no good one
    columns = read_rrd_columns(rrd)
    for case in CASES:
        case.check(columns)


def test_topic_selection_in_peer_mode_with_a_urdf(tmp_path):
    """-t picks exactly its topics (with or without the leading slash); peer to peer, no router;
    --urdf: the model's links as Rerun's URDF importer logs them, its joint between named frames."""
    port = free_port()
    session = listening_peer(port)
    node = ros2.Node(session, "cabin")
    rrd = tmp_path / "selected.rrd"
    picked = {c.topic: c for c in CASES if c.topic in ("/chatter", "/cabin/temperature")}
    try:
        with viewer(session, rrd, "--zenoh-mode", "peer", "--zenoh-connect", f"tcp/127.0.0.1:{port}",
                    "-t", "/chatter", "-t", "cabin/temperature", "--urdf", str(URDF)):
            pubs = {c.topic: node.publisher(c.topic, c.type_name) for c in CASES[:-1]}  # CAN: no frame keys here
            wanted = {pubs[t].key for t in picked}
            wait_for(lambda: subscribed(session, wanted), "the viewer subscribed to the two selected topics")
            for case in CASES[:-1]:
                pubs[case.topic].put(case.msg)
            wait_for(lambda: viewer_stats(session)["logged"] >= 2, "the viewer logging the two selected samples")
            stats = viewer_stats(session)
    finally:
        node.close()
        session.close()
    assert {k for k in stats["subscriptions"] if not k.startswith("vehicle/")} == wanted
    assert stats["logged"] == 2
    columns = read_rrd_columns(rrd)
    for case in picked.values():
        case.check(columns)
    assert not [e for e in columns if e.startswith("/ros2/") and not e.startswith(("/ros2/chatter", "/ros2/cabin/t"))]
    body = columns["/car/visual_geometries/base_link/visual_0"]
    assert body["Boxes3D:half_sizes"] == [[[2.0, 1.0, 0.75]]] and body["CoordinateFrame:frame"] == [["base_link"]]
    joint = columns["/tf_static"]
    assert (joint["Transform3D:parent_frame"], joint["Transform3D:child_frame"]) == ([["base_link"]], [["lidar"]])
    assert joint["Transform3D:translation"] == [[[0.5, 0.0, 1.0]]]


def test_topic_whose_publisher_goes_is_unsubscribed(lone_router, tmp_path):
    session = zenoh_session(lone_router.endpoint)
    node = ros2.Node(session, "talker")
    rrd = tmp_path / "gone.rrd"
    try:
        with viewer(session, rrd, "--zenoh-connect", lone_router.endpoint, "--auto-subscribe"):
            first, second = node.publisher("/chatter", "std_msgs/msg/String"), node.publisher(
                "/chatter", "std_msgs/msg/String")  # two publishers on one key: the second keeps it alive
            wait_for(lambda: subscribed(session, {first.key}), "the viewer subscribed to /chatter")
            first.undeclare()
            second.put(ros2.MESSAGE_TYPES["std_msgs/msg/String"]("still here"))
            wait_for(lambda: viewer_stats(session)["logged"] >= 1, "the viewer logging the sample")
            assert first.key in viewer_stats(session)["subscriptions"]
            second.undeclare()
            wait_for(lambda: first.key not in viewer_stats(session)["subscriptions"], "the viewer unsubscribing")
    finally:
        node.close()
        session.close()
    lines = read_rrd_columns(rrd)["/discovery/subscriptions"]["TextLog:text"]
    assert lines == [["+ /chatter [std_msgs/msg/String]"], ["- /chatter [std_msgs/msg/String]"]]


def test_a_transient_local_topic_published_before_the_viewer_started_is_shown(lone_router, tmp_path):
    """/tf_static as robot_state_publisher sends it: once, at start, TRANSIENT_LOCAL (rmw_zenoh keeps
    it in an AdvancedPublisher's cache); the viewer started later asks the cache, as rmw_zenoh's
    subscribers do. A VOLATILE topic's earlier sample stays unseen (the control)."""
    conf = base_config()  # as rmw_zenoh's session config: timestamping on (its publishers' caches need it)
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([lone_router.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("timestamping/enabled", "true")
    session = zenoh.open(conf)
    node = ros2.Node(session, "robot_state_publisher")
    rrd = tmp_path / "late.rrd"
    msgs = ros2.MESSAGE_TYPES
    tf = msgs["tf2_msgs/msg/TFMessage"]([msgs["geometry_msgs/msg/TransformStamped"](
        header=msgs["std_msgs/msg/Header"](frame_id="base_link"), child_frame_id="lidar")])
    try:
        static = node.publisher("/tf_static", "tf2_msgs/msg/TFMessage", transient_local=1)
        chatter = node.publisher("/chatter", "std_msgs/msg/String")
        static.put(tf)
        chatter.put(msgs["std_msgs/msg/String"]("before the viewer"))
        with viewer(session, rrd, "--zenoh-connect", lone_router.endpoint, "--auto-subscribe"):
            wait_for(lambda: subscribed(session, {static.key, chatter.key}), "the viewer subscribed to both topics")
            wait_for(lambda: viewer_stats(session)["logged"] >= 1, "the viewer logging the cached /tf_static")
            chatter.put(msgs["std_msgs/msg/String"]("after"))
            wait_for(lambda: viewer_stats(session)["logged"] >= 2, "the viewer logging /chatter's second sample")
            stats = viewer_stats(session)
    finally:
        node.close()
        session.close()
    assert stats["logged"] == 2 and not stats["malformed"]
    columns = read_rrd_columns(rrd)
    joint = columns["/tf/base_link/lidar"]
    assert (joint["Transform3D:parent_frame"], joint["Transform3D:child_frame"]) == ([["base_link"]], [["lidar"]])
    assert columns["/ros2/chatter"]["TextLog:text"] == [["after"]]


def test_ros_domain_discovers_that_domain_only(lone_router, tmp_path):
    session = zenoh_session(lone_router.endpoint)
    nodes = [ros2.Node(session, "talker", domain_id=d) for d in (0, 7)]
    try:
        pubs = [n.publisher("/chatter", "std_msgs/msg/String") for n in nodes]
        with viewer(session, tmp_path / "d.rrd", "--zenoh-connect", lone_router.endpoint, "--auto-subscribe",
                    "--ros-domain", "7"):
            wait_for(lambda: subscribed(session, {pubs[1].key}), "the viewer subscribed to domain 7's /chatter")
            pubs[1].put(ros2.MESSAGE_TYPES["std_msgs/msg/String"]("seven"))
            wait_for(lambda: viewer_stats(session)["logged"] >= 1, "the viewer logging domain 7's sample")
            stats = viewer_stats(session)
    finally:
        for n in nodes:
            n.close()
        session.close()
    assert {k for k in stats["subscriptions"] if not k.startswith("vehicle/")} == {pubs[1].key}
    assert read_rrd_columns(tmp_path / "d.rrd")["/ros2/domain7/chatter"]["TextLog:text"] == [["seven"]]


def test_a_transient_local_publisher_seen_after_a_volatile_one_on_its_topic_gets_its_cache_asked(lone_router):
    """/map of two publishers, a VOLATILE one and a TRANSIENT_LOCAL one that published before the
    viewer started. The viewer learns of them in either order (its liveliness history); here the
    VOLATILE token first, so its first subscriber asks no cache: it must be replaced by one that
    does when the TRANSIENT_LOCAL token comes, or the map never arrives."""
    from types import SimpleNamespace

    from canbench.viewer import Viewer
    conf = base_config()
    for key, value in (("mode", '"client"'), ("connect/endpoints", json.dumps([lone_router.endpoint])),
                       ("scouting/multicast/enabled", "false"), ("timestamping/enabled", "true")):
        conf.insert_json5(key, value)
    publishing, viewing = zenoh.open(conf), zenoh_session(lone_router.endpoint)
    node = ros2.Node(publishing, "map_server")
    grid_type = "nav_msgs/msg/OccupancyGrid"
    grid = ros2.MESSAGE_TYPES[grid_type](data=[0, 100, -1])
    live = Viewer(viewing, [], True)
    try:
        latched = node.publisher("/map", grid_type, transient_local=1)
        latched.put(grid)
        volatile = ros2.publisher_token(0, node.zid, 0, 99, "/", "map_relay", "/map", grid_type,
                                        latched.type_hash, "::,10:,:,:,,")
        for token in (volatile, latched.token_key):
            live._on_ros_token(SimpleNamespace(key_expr=token, kind=zenoh.SampleKind.PUT))
        assert live.asks_caches == {latched.key}
        sample = live.samples.get(timeout=10)  # the cache's reply
        assert sample.key == latched.key and list(ros2.MESSAGE_TYPES[grid_type].deserialize(sample.payload).data) == [
            0, 100, -1]
    finally:
        for sub in live.subscribers.values():
            sub.undeclare()  # type: ignore[attr-defined]
        node.close()
        publishing.close()
        viewing.close()
