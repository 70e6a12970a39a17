"""A device of your own in the bridge's place (canbench.device, `make test DEVICE=host:PORT`),
without Docker: DEVICE is checked, scenarios a device cannot stand in for are refused, the
compose override publishes the router on loopback only and binds the hub's socket directory,
the device's settings survive a shell, and the device's identity, as written, gets a session
on a router at 127.0.0.1 (TLS to an IP address) and may do the bridge's job. The run itself is
tests/compose/test_device.py."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
import zenoh
from test_compose_privileges import defaults, merged
from test_identities import Inbox, free_port

from canbench import compose, device, faults, identities, runkeys, scenario

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
SCENARIOS = REPO / "scenarios"


@pytest.mark.parametrize("spec,port", [("host:7448", 7448), ("host:65535", 65535), ("host:1024", 1024)])
def test_a_host_device_and_its_port(spec, port):
    assert device.parse(spec) == device.Device(port)
    assert device.parse(spec).endpoint() == f"tls/127.0.0.1:{port}"


@pytest.mark.parametrize("spec,says", [("7448", "expected host:PORT"), ("can0", "expected host:PORT"),
                                       (" host:7448", "expected host:PORT"),
                                       ("host:", "expected host:PORT"), ("host:0.0.0.0:7448", "expected host:PORT"),
                                       ("host:80", "not in 1024-65535"), ("host:70000", "not in 1024-65535")])
def test_a_device_that_is_not_a_host_port_is_refused_with_why(spec, says):
    with pytest.raises(ValueError, match=says):
        device.parse(spec)


def test_what_a_device_cannot_stand_in_for_is_refused_at_its_file():
    faults = scenario.load(SCENARIOS / "bridge-faults.yaml")
    partition = scenario.load(SCENARIOS / "stale-commands.yaml")
    consumer = scenario.load(SCENARIOS / "bridge-router.yaml")
    smoke = scenario.load(SCENARIOS / "smoke.yaml")
    assert device.refusals(smoke, "userspace") == []
    # a stop or a kill of the device is bench-run's, which can start again only what it started
    [why] = device.refusals(faults, "userspace")
    assert why.startswith(str(faults.path)) and "fault steps bridge_kill, bridge_term stop the device" in why
    assert "give DEVICE_CMD" in why
    assert device.refusals(faults, "userspace", restartable=True) == []
    # the router's faults, an ECU's, a flood and a partition (of the device's own listener) act on the
    # bench's side: a device meets them as the bridge does
    for name in ("router-faults.yaml", "can-flood.yaml", "network-partition.yaml"):
        assert device.refusals(scenario.load(SCENARIOS / name), "userspace") == [], name
    assert device.refusals(partition, "userspace") == []
    [why] = device.refusals(consumer, "userspace")
    assert "consumer: bridge" in why
    [why] = device.refusals(smoke, "kernel")
    assert "BENCH_CAN_MODE=kernel" in why
    listening = dataclasses.replace(smoke, bridge={**smoke.bridge, "listen": "tls/127.0.0.1:7449"})
    [why] = device.refusals(listening, "userspace")
    assert "bridge.listen" in why and "host's interfaces" in why


def test_the_router_is_published_on_loopback_only_and_the_bus_on_the_host():
    sc = scenario.load(SCENARIOS / "smoke.yaml")
    out = compose.compose_override(sc, "/scenarios/smoke.yaml", device=device.Device(7448),
                                   canbus_dir="/tmp/canbench-bus.x")
    doc = defaults(merged(out))
    published = {name: svc["ports"] for name, svc in doc["services"].items() if svc.get("ports")}
    assert published == {"router": [f"127.0.0.1:7448:{identities.PORT}"]}
    assert out["volumes"]["canbus"]["driver_opts"] == {"type": "none", "o": "bind", "device": "/tmp/canbench-bus.x"}
    # the rest of the run is the bench's as without a device: every service keeps its hardening
    for name, svc in doc["services"].items():
        assert svc.get("cap_drop") == ["ALL"] and svc.get("read_only") is True, name


def test_a_partitions_device_is_published_to_the_listener_the_partition_cuts():
    # the partition drops the router's second listener only (the captures and ECUs keep theirs): the
    # device's published port leads there, as the bench's bridge dials it
    sc = scenario.load(SCENARIOS / "network-partition.yaml")
    out = compose.compose_override(sc, "/scenarios/network-partition.yaml", device=device.Device(7448),
                                   canbus_dir="/tmp/canbench-bus.x")
    router = defaults(merged(out))["services"]["router"]
    assert router["ports"] == [f"127.0.0.1:7448:{faults.PARTITION_PORT}"]
    assert f"tls/0.0.0.0:{faults.PARTITION_PORT}" in router["command"]


def test_the_settings_survive_the_shell_that_starts_the_device(tmp_path):
    settings = {"ZENOH_NODE_CAN": "vcan0,vcan1", "ODD": "a b 'c' \"d\" $HOME `x` ;&"}
    env = tmp_path / "device.env"
    env.write_text(device.env_file(settings))
    show = "import os, json; print(json.dumps({k: os.environ[k] for k in ('ZENOH_NODE_CAN', 'ODD')}))"
    shown = subprocess.run(["bash", "-c", f'set -a; . "{env}"; "$0" -c "$1"', sys.executable, show],
                           capture_output=True, text=True, check=True).stdout
    assert json.loads(shown) == settings


def test_the_compose_override_command_refuses_and_writes_the_settings(tmp_path):
    def run(name: str, *extra: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "canbench.cli", "compose-override", str(SCENARIOS / name),
                               "--device", "host:7448", *extra], capture_output=True, text=True, cwd=REPO)
    refused = run("bridge-faults.yaml", "--device-canbus", str(tmp_path))
    assert refused.returncode == 2 and "DEVICE=host:7448:" in refused.stderr and "fault steps" in refused.stderr
    restartable = run("bridge-faults.yaml", "--device-canbus", str(tmp_path), "--device-restartable")
    assert restartable.returncode == 0, restartable.stderr
    assert "--device-canbus" in run("smoke.yaml").stderr
    ok = run("smoke.yaml", "--device-canbus", str(tmp_path), "--device-env", str(tmp_path / "device.env"))
    assert ok.returncode == 0, ok.stderr
    assert "ZENOH_NODE_CAN=vcan0\n" in (tmp_path / "device.env").read_text()
    assert "127.0.0.1:7448:7447" in ok.stdout


@contextlib.contextmanager
def device_and_consumer(tmp_path: Path):
    """A router with the run's identities and ACL on a loopback port, the orchestrator's session
    (the consumer) and the device's as its identity is written for it, on the host's paths."""
    root, port = tmp_path / "identities", free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    names = identities.generate(root, device=(str(root), endpoint))
    assert identities.DEVICE_IDENTITY in names
    router = json.loads((root / "router" / "zenohd.json5").read_text())
    router["listen"]["endpoints"] = [endpoint]
    text = json.dumps(router).replace(identities.mount_of("router"), str(root / "router"))
    rconf = zenoh.Config()
    for key, value in json.loads(text).items():
        rconf.insert_json5(key, json.dumps(value))
    conf_text = (root / identities.DEVICE_IDENTITY / "zenoh.json5").read_text()
    assert str(root / identities.DEVICE_IDENTITY / "key.pem") in conf_text  # the host's paths, as written
    with zenoh.open(rconf) as _router:
        consumer_conf = json.loads((root / "orchestrator" / "zenoh.json5").read_text())
        consumer_conf |= {"mode": "client", "connect": {"endpoints": [endpoint]},
                          "scouting": {"multicast": {"enabled": False}}}
        text = json.dumps(consumer_conf).replace(identities.mount_of("orchestrator"), str(root / "orchestrator"))
        cconf = zenoh.Config()
        for key, value in json.loads(text).items():
            cconf.insert_json5(key, json.dumps(value))
        with zenoh.open(cconf) as consumer, zenoh.open(zenoh.Config.from_file(
                str(root / identities.DEVICE_IDENTITY / "zenoh.json5"))) as dev:
            yield consumer, dev


def test_the_devices_identity_as_written_gets_a_session_on_loopback_and_does_the_bridges_job(tmp_path):
    with device_and_consumer(tmp_path) as (consumer, dev):
        inbox = Inbox()
        keep = [consumer.declare_subscriber("vehicle/can/rx", inbox),
                dev.liveliness().declare_token("vehicle/can/bridges/zenoh-node/vcan0/client")]
        # the router answers the consumer's token query after its subscription: then the put finds it
        runkeys.wait_token(consumer, runkeys.bridges("vehicle/can"), 5)
        dev.put("vehicle/can/rx", b"from-the-device")  # the router's ACL lets it publish rx as the bridge
        inbox.wait_for("from-the-device")
        del keep


def test_a_device_that_announces_nothing_is_seen_ready_by_its_subscription_under_the_acl(tmp_path):
    # DEVICE_ANNOUNCES=0: the orchestrator learns of the device's subscription to the tx keys through
    # the router (a publisher's matching status), with the ACL the run has; nothing before it
    with device_and_consumer(tmp_path) as (consumer, dev):
        keys = ["vehicle/can/vcan0/tx", "vehicle/can/vcan1/tx"]
        with pytest.raises(TimeoutError, match="no subscriber on vehicle/can/vcan0/tx after 0.3 s"):
            runkeys.wait_subscribed(consumer, keys, 0.3)
        first = dev.declare_subscriber("vehicle/can/vcan0/tx", lambda _s: None)
        with pytest.raises(TimeoutError, match="no subscriber on vehicle/can/vcan1/tx"):
            runkeys.wait_subscribed(consumer, keys, 0.3)
        second = dev.declare_subscriber("vehicle/can/vcan1/tx", lambda _s: None)
        runkeys.wait_subscribed(consumer, keys, 5)
        first.undeclare()
        second.undeclare()


def test_open_access_writes_a_plain_tcp_device(tmp_path):
    identities.generate(tmp_path / "i", secure=False, device=(str(tmp_path / "i"), "tcp/127.0.0.1:7448"))
    conf = json.loads((tmp_path / "i" / identities.DEVICE_IDENTITY / "zenoh.json5").read_text())
    assert conf["connect"]["endpoints"] == ["tcp/127.0.0.1:7448"] and "transport" not in conf
    assert conf["scouting"]["multicast"]["enabled"] is False and conf["listen"]["endpoints"] == []


def test_the_devices_certificate_is_a_clients_and_its_config_takes_the_scenarios_mode(tmp_path):
    root = tmp_path / "i"
    identities.generate(root, device=(str(root), "tls/127.0.0.1:7448"), device_mode="peer")
    d = root / identities.DEVICE_IDENTITY
    text = subprocess.run(["openssl", "x509", "-in", str(d / "cert.pem"), "-noout", "-text"], capture_output=True,
                          text=True, check=True).stdout
    # its key lies on the host: no router's name in it, client authentication only
    assert "Subject Alternative Name" not in text and "TLS Web Client Authentication" in text
    assert "TLS Web Server Authentication" not in text and "CN = bridge" in text
    assert (d / "key.pem").stat().st_mode & 0o077 == 0
    conf = json.loads((d / "zenoh.json5").read_text())
    # a peer's listener would be on every interface by default: none, and no multicast scouting
    assert conf["mode"] == "peer" and conf["listen"]["endpoints"] == []
    assert conf["scouting"]["multicast"]["enabled"] is False


@pytest.mark.parametrize("merge", ["replace", "deep"])
def test_the_bus_directory_binds_whether_compose_replaces_or_merges_the_volume(merge):
    # docker-compose 1.29 replaces a top-level volume an override names, compose v2 merges it key by key
    base = defaults(yaml.safe_load((REPO / "compose.yaml").read_text()))["volumes"]["canbus"]
    sc = scenario.load(SCENARIOS / "smoke.yaml")
    mine = compose.compose_override(sc, "/scenarios/smoke.yaml", device=device.Device(7448),
                                    canbus_dir="/tmp/canbench-bus.x")["volumes"]["canbus"]
    merged_volume = mine if merge == "replace" else {**base, "driver_opts": {**base["driver_opts"],
                                                                             **mine["driver_opts"]}}
    assert merged_volume["driver_opts"] == {"type": "none", "o": "bind", "device": "/tmp/canbench-bus.x"}
