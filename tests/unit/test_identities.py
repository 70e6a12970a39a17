"""The bench's identities and access control (canbench.identities) with the real Zenoh: the
router config `canbench identities` writes, opened as a Zenoh router in this process on
loopback (the same zenoh 1.10.2 core as zenohd), and a client per identity with the Zenoh
config written for it. What each identity may do is what docs/access-control.md's table says:
the bridge publishes rx and answers stats, the orchestrator commands, the capture only
subscribes, the ECU only coordinates; a client without a certificate and one whose certificate
another CA signed get no session. The compose run of the same (scenarios/security.yaml) is
tests/compose/test_security.py."""
from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import pytest
import zenoh

from canbench import identities, runkeys

pytestmark = pytest.mark.unit

P = "vehicle/can"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(conf: dict, root: Path, identity: str) -> zenoh.Config:
    """conf with the container paths (/run/zenoh...) pointing at root/<identity>."""
    text = json.dumps(conf).replace(identities.mount_of(identity), str(root / identity))
    c = zenoh.Config()
    for key, value in json.loads(text).items():
        c.insert_json5(key, json.dumps(value))
    return c


class Net:
    def __init__(self, root: Path, secure: bool = True):
        self.root, self.port = root, free_port()
        identities.generate(root, secure=secure)
        router = json.loads((root / "router" / "zenohd.json5").read_text())
        self.scheme = "tls" if secure else "tcp"
        router["listen"]["endpoints"] = [f"{self.scheme}/127.0.0.1:{self.port}"]
        self.sessions = [zenoh.open(config(router, root, "router"))]

    def client(self, directory: str, timeout_ms: int | None = None) -> zenoh.Session:
        conf = json.loads((self.root / directory / "zenoh.json5").read_text())
        conf |= {"mode": "client", "connect": {"endpoints": [f"{self.scheme}/localhost:{self.port}"]},
                 "scouting": {"multicast": {"enabled": False}}}
        if timeout_ms is not None:
            conf["connect"]["timeout_ms"] = timeout_ms
        session = zenoh.open(config(conf, self.root, directory))
        self.sessions.append(session)
        return session

    def close(self) -> None:
        for s in reversed(self.sessions):
            s.close()


class Inbox:
    def __init__(self):
        self.items: list[str] = []
        self.cv = threading.Condition()

    def __call__(self, sample) -> None:
        with self.cv:
            self.items.append(sample.payload.to_bytes().decode(errors="replace"))
            self.cv.notify_all()

    def wait_for(self, item: str, timeout_s: float = 5) -> None:
        with self.cv:
            assert self.cv.wait_for(lambda: item in self.items, timeout_s), f"{item} never arrived: {self.items}"


@pytest.fixture
def net(tmp_path):
    n = Net(tmp_path / "identities")
    yield n
    n.close()


def test_each_identity_may_do_its_job_and_nothing_else(net):
    bridge, orch, cap, ecu = (net.client(n) for n in ("bridge", "orchestrator", "capture", "ecu"))
    commands, on_rx, captured, coordination = Inbox(), Inbox(), Inbox(), Inbox()
    keep = [  # zenoh undeclares what is dropped
        bridge.declare_subscriber(f"{P}/tx", commands),
        bridge.declare_queryable(f"{P}/bridges/zenoh-node/stats", lambda q: q.reply(q.key_expr, b'{"buses": []}')),
        bridge.liveliness().declare_token(f"{P}/bridges/zenoh-node/vcan0/client"),
        orch.declare_subscriber(f"{P}/rx", on_rx),
        cap.declare_subscriber(f"{P}/**", captured),
        orch.declare_subscriber("bench/runs/r/ecus/*/done", coordination),
        cap.liveliness().declare_token(runkeys.zenoh_capture_ready("r")),
        orch.liveliness().declare_token(runkeys.capture_ready("r")),
    ]
    # the orchestrator sees the bridge's and the capture's tokens, the ECU the run's
    runkeys.wait_token(orch, runkeys.bridges(P), 5)
    runkeys.wait_token(orch, runkeys.zenoh_capture_ready("r"), 5)
    runkeys.wait_token(ecu, runkeys.capture_ready("r"), 5)
    assert [r.ok.payload.to_bytes() for r in orch.get(runkeys.bridge_stats(P)) if r.ok] == [b'{"buses": []}']

    for who, session in (("ecu", ecu), ("capture", cap), ("orchestrator", orch)):
        session.put(f"{P}/tx", who.encode())
    bridge.put(f"{P}/rx", b"frame")
    ecu.put("bench/runs/r/ecus/e/done", b"ecu-done")
    commands.wait_for("orchestrator")
    on_rx.wait_for("frame")
    captured.wait_for("frame")
    coordination.wait_for("ecu-done")
    # a query after the puts, on each denied session: the router has handled their puts by then
    for session in (ecu, cap):
        list(session.get("bench/runs/r/sync", timeout=2))
    assert commands.items == ["orchestrator"]  # the ECU's and the capture's commands never arrived
    # the ECU has no rights on the vehicle's keys: no stats, no token, no rx
    assert [r for r in ecu.get(runkeys.bridge_stats(P), timeout=2) if r.ok] == []
    assert [r for r in ecu.liveliness().get(runkeys.bridges(P), timeout=2) if r.ok] == []
    # what the ECU may not publish never reaches a subscriber either
    ecu.put(f"{P}/rx", b"forged")
    bridge.put(f"{P}/rx", b"second")
    on_rx.wait_for("second")
    assert "forged" not in on_rx.items
    del keep


@pytest.mark.parametrize("directory", ["anonymous", "rogue-bridge"])
def test_no_session_without_a_certificate_of_the_run(net, directory):
    with pytest.raises(zenoh.ZError):
        net.client(directory, timeout_ms=2000)


def test_open_mode_has_no_tls_and_no_acl(tmp_path):
    n = Net(tmp_path / "identities", secure=False)
    try:
        assert not (tmp_path / "identities" / "bridge" / "cert.pem").exists()
        conf = json.loads((tmp_path / "identities" / "router" / "zenohd.json5").read_text())
        assert "access_control" not in conf and conf["listen"]["endpoints"][0].startswith("tcp/")
        bridge, anyone = n.client("bridge"), n.client("anonymous")
        commands = Inbox()
        sub = bridge.declare_subscriber(f"{P}/tx", commands)
        token = bridge.liveliness().declare_token(f"{P}/bridges/zenoh-node/vcan0/client")
        runkeys.wait_token(anyone, runkeys.bridges(P), 5)  # the bridge's subscriber is in place by then
        anyone.put(f"{P}/tx", b"anyone")  # open: whoever reaches the router may command
        commands.wait_for("anyone")
        token.undeclare()
        sub.undeclare()
    finally:
        n.close()


def test_keys_are_not_world_readable_and_the_ca_key_is_gone(tmp_path):
    root = tmp_path / "identities"
    identities.generate(root)
    keys = sorted(root.glob("*/key.pem"))
    assert {k.parent.name for k in keys} == {*identities.IDENTITIES, identities.ROGUE}
    assert all(k.stat().st_mode & 0o007 == 0 for k in keys)
    assert not list(root.rglob("ca.key")) and not (root / "anonymous" / "key.pem").exists()
    with pytest.raises(RuntimeError, match="not empty"):
        identities.generate(root)


def test_the_security_scenarios_probes_are_refused(net, tmp_path, monkeypatch):
    """canbench.security's probes and the orchestrator's observation, against the real Zenoh: the
    anonymous and the rogue probe get no session, the ECU's does and puts, but nothing reaches the
    bridge; security.json says so, and check access_control passes on it (and fails when the
    rogue bridge's token shows)."""
    from types import SimpleNamespace

    from canbench import security
    monkeypatch.setattr(security, "CONNECT_TIMEOUT_MS", 1000)  # loopback: a refusal is at once
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    configs = tmp_path / "configs"
    configs.mkdir()
    for d in ("anonymous", "ecu", "rogue-bridge"):
        text = (net.root / d / "zenoh.json5").read_text().replace(identities.MOUNT, str(net.root / d))
        (configs / f"{d}.json5").write_text(text)
    bridge, orch = net.client("bridge"), net.client("orchestrator")
    commands = Inbox()
    keep = [bridge.declare_subscriber(f"{P}/tx", commands),
            bridge.liveliness().declare_token(f"{P}/bridges/zenoh-node/vcan0/client"),
            orch.liveliness().declare_token(runkeys.capture_ready("r"))]
    runkeys.wait_token(orch, runkeys.bridges(P), 5)  # as the bench: the bridge subscribes before the token
    endpoint = f"tls/localhost:{net.port}"
    results = {name: security.probe(name, endpoint, "r", run_dir, 5, config_file=str(configs / f"{name}.json5"))
               for name in security.PROBES}
    assert [a["session"] for a in results["anonymous"]["attempts"]] == [False, False]
    assert results["rogue-bridge"]["session"] is False
    assert results["ecu"]["session"] is True and results["ecu"]["put"] == 5 and results["ecu"]["capture_ready_seen"]
    orch.put(f"{P}/tx", b"after")  # the orchestrator's command after the probes' arrives; theirs never did
    commands.wait_for("after")
    assert commands.items == ["after"]
    scenario = SimpleNamespace(raw={"security": {"probes": list(security.PROBES), "frames": 5}})
    run = SimpleNamespace(scenario=scenario, run_dir=run_dir, session=orch, prefix=P)
    security.observe(run)
    seen = json.loads((run_dir / "security.json").read_text())
    assert seen["rogue_bridge_tokens"] == [] and set(seen["probes"]) == set(security.PROBES)
    result = SimpleNamespace(scenario=scenario, run_dir=run_dir, buses=[], bridge_stats=None)
    assert security.check(result) == []
    # a rogue bridge that got in is named
    rogue = bridge.liveliness().declare_token(f"{P}/bridges/{security.ROGUE_NODE}/vcan0/client")
    runkeys.wait_token(orch, f"{P}/bridges/{security.ROGUE_NODE}/**", 5)
    security.observe(run)
    assert any("rogue bridge" in p for p in security.check(result)), (run_dir / "security.json").read_text()
    rogue.undeclare()
    del keep


def test_ros2_output_reaches_the_viewer(tmp_path):
    """With the bridge's ROS 2 output (scenario ros2-output), the viewer sees rmw_zenoh's tokens
    (its subscription is @ros2_lv/**) and the data key; the ECU sees neither."""
    from canbench import scenario
    sc = scenario.load(Path(__file__).resolve().parents[2] / "scenarios" / "ros2-output.yaml")
    (data_key,) = runkeys.ros2_data_keys(sc)
    root = tmp_path / "identities"
    port = free_port()
    identities.generate(root, ros2_keys=(data_key,), ros2_domains=(0,))
    router = json.loads((root / "router" / "zenohd.json5").read_text())
    router["listen"]["endpoints"] = [f"tls/127.0.0.1:{port}"]
    n = Net.__new__(Net)
    n.root, n.port, n.scheme, n.sessions = root, port, "tls", [zenoh.open(config(router, root, "router"))]
    try:
        bridge, viewer, ecu = n.client("bridge"), n.client("viewer"), n.client("ecu")
        token = bridge.liveliness().declare_token("@ros2_lv/0/abc/0/0/NN/%/%/can_bridge")
        runkeys.wait_token(viewer, "@ros2_lv/**", 5)
        got = Inbox()
        sub = viewer.declare_subscriber(data_key, got)
        # put until it arrives: the viewer's subscription reaches the bridge some time after it is made
        runkeys.wait_until(lambda: bridge.put(data_key, b"frame") or "frame" in got.items, 5, "the ROS 2 sample",
                           step_s=0.05)
        assert [r for r in ecu.liveliness().get("@ros2_lv/**", timeout=1) if r.ok] == []
        sub.undeclare()
        token.undeclare()
    finally:
        n.close()
