"""Least privilege of the compose bench, without Docker: compose.yaml merged with the override
`canbench compose-override` writes for every shipped scenario (with and without the recording
viewer, userspace and kernel bus). Every service runs as a non-root user, drops every
capability, sets no-new-privileges and has a read-only root file system; only the kernel-vcan
bus gets root with NET_ADMIN; only fault scenarios mount Docker's socket; each service mounts its
own Zenoh identity only; nothing listens on 0.0.0.0 but the routers (docs/access-control.md)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from canbench import compose, scenario

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
SCENARIOS = sorted(p for p in (REPO / "scenarios").rglob("*.yaml") if "traces" not in p.parts)
VAR = re.compile(r"\$\{([A-Z0-9_]+)(?::?[-?]([^}]*))?\}")
# the identities each service may mount, and where (canbench.identities.mount_of)
IDENTITY_OF = {"router": {"router"}, "router2": {"router2"}, "bridge": {"bridge"}, "viewer": {"viewer"},
               "orchestrator": {"orchestrator", "capture"}, "bridge-rogue": {"rogue-bridge"},
               "probe-anonymous": {"anonymous"}, "probe-ecu": {"ecu"}, "probe-rogue-bridge": {"rogue-bridge"}}


def defaults(value):
    """What compose makes of value with none of the bench's variables set: ${X:-d} -> d
    (${X:?message} -> a marker: compose would stop with the message)."""
    if isinstance(value, str):
        return VAR.sub(lambda m: "<required>" if "?" in m.group(0) else (m.group(2) or ""), value)
    if isinstance(value, list):
        return [defaults(v) for v in value]
    if isinstance(value, dict):
        return {k: defaults(v) for k, v in value.items()}
    return value


def env_list(env) -> list[str]:
    return [f"{k}={v}" for k, v in env.items()] if isinstance(env, dict) else list(env)


def merged(override: dict) -> dict:
    """compose.yaml's services with the override's keys on top (compose merges lists such as
    volumes and environment; the test only needs every key either file sets)."""
    base = yaml.safe_load((REPO / "compose.yaml").read_text())
    services = {name: dict(svc) for name, svc in base["services"].items()}
    for name, svc in override["services"].items():
        target = services.setdefault(name, {})
        for key, value in svc.items():
            if key in ("volumes",) and key in target:
                target[key] = [*target[key], *value]
            elif key == "environment" and key in target:
                target[key] = [*env_list(target[key]), *env_list(value)]
            else:
                target[key] = value
    return {"services": services, "volumes": base.get("volumes", {}),
            "networks": {**base.get("networks", {}), **override.get("networks", {})}}


def variants() -> list:
    return [pytest.param(path, viewer, mode, id=f"{path.stem}-{'viewer-' if viewer else ''}{mode}")
            for path in SCENARIOS for viewer in (False, True) for mode in ("userspace", "kernel")]


def override_of(path: Path, viewer: bool, mode: str) -> dict:
    sc = scenario.load(path)
    return compose.compose_override(sc, f"/scenarios/{path.name}", viewer=viewer, can_mode=mode)


def test_the_shipped_set_is_there():
    names = {p.stem for p in SCENARIOS}
    assert {"smoke", "security", "router-faults", "two-routers", "bridge-router", "peer"} <= names


@pytest.mark.parametrize("path,viewer,mode", variants())
def test_every_service_is_unprivileged(path, viewer, mode):
    sc = scenario.load(path)
    doc = defaults(merged(override_of(path, viewer, mode)))
    for name, svc in doc["services"].items():
        where = f"{path.name} {mode}{' viewer' if viewer else ''}: service {name}"
        assert not svc.get("privileged"), where
        assert svc.get("network_mode", "") in ("", "service:bus"), f"{where}: network_mode {svc['network_mode']}"
        assert "pid" not in svc and "ipc" not in svc, where
        assert svc.get("cap_drop") == ["ALL"], f"{where}: cap_drop {svc.get('cap_drop')}"
        assert "no-new-privileges:true" in svc.get("security_opt", []), f"{where}: no no-new-privileges"
        assert svc.get("read_only") is True, f"{where}: the root file system is writable"
        user = str(svc.get("user", ""))
        uid, _, gid = user.partition(":")
        if name == "bus" and mode == "kernel":
            # kernel vcan: `ip link add` needs root with NET_ADMIN, in that container only
            assert (user, svc.get("cap_add")) == ("0:0", ["NET_ADMIN"]), where
            continue
        assert uid.isdigit() and gid.isdigit(), f"{where}: user {user!r} (a numeric uid:gid, as bench-run sets)"
        assert uid != "0" and gid != "0", f"{where}: runs as root ({user})"
        assert not svc.get("cap_add"), f"{where}: cap_add {svc.get('cap_add')}"
        docker_socket = [v for v in svc.get("volumes", []) if "docker.sock" in str(v)]
        if docker_socket:
            assert name == "orchestrator" and sc.faults, f"{where}: Docker's socket without fault steps"
        for v in svc.get("volumes", []):
            v = str(v)
            if "<required>/" in v:  # an identity: the service's own, read-only
                ident, mount, opts = v.split("<required>/", 1)[1].split(":")
                assert ident in IDENTITY_OF.get(name, {"ecu"} if name.startswith("ecu-") else set()), \
                    f"{where}: mounts identity {ident}"
                assert opts == "ro", f"{where}: identity {ident} writable"


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_only_the_routers_listen_beyond_loopback(path):
    sc = scenario.load(path)
    doc = defaults(merged(override_of(path, False, "userspace")))
    for name, svc in doc["services"].items():
        env = svc.get("environment", [])
        listen = [e for e in env if str(e).startswith("ZENOH_LISTEN=")]
        if "listen" not in sc.bridge:
            assert all("0.0.0.0" not in e for e in listen), f"{path.name}: {name} {listen}"
        # the bench's endpoints are TLS by default (tcp only with BENCH_ACCESS=open)
        for e in env:
            if str(e).startswith(("ZENOH_ROUTER_ADDRESS=", "BENCH_ROUTER=", "BENCH_CONSUMER=")):
                assert str(e).split("=", 1)[1].startswith("tls/"), f"{path.name}: {name} {e}"


def test_the_bus_socket_directory_is_the_bench_groups_only():
    doc = defaults(yaml.safe_load((REPO / "compose.yaml").read_text()))
    opts = doc["volumes"]["canbus"]["driver_opts"]
    assert opts["type"] == "tmpfs"
    fields = dict(o.split("=") for o in opts["o"].split(","))
    assert fields["mode"] == "0770" and fields["uid"] != "0" and fields["gid"] != "0", opts
    # the services that share the socket run in that group
    users = {s["user"] for n, s in doc["services"].items() if "canbus:/run/ucan" in s.get("volumes", [])}
    assert users == {f"{fields['uid']}:{fields['gid']}"}, users


def test_every_one_off_container_is_offline():
    """The containers scripts and make start outside compose (validation, suite plans and summaries,
    canbench for scenario writing, make shell) reach nothing: each runs with --network none."""
    found = []
    for path in [REPO / "Makefile", *sorted((REPO / "scripts").iterdir())]:
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"\bdocker run\b", line) and not line.lstrip().startswith("#"):
                found.append((f"{path.name}:{n}", "--network none" in line))
    assert found and all(offline for _, offline in found), [where for where, offline in found if not offline]


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_no_service_is_reachable_from_beyond_the_bench(path):
    # no port published on the host's interfaces, no network but the bench's own
    doc = defaults(merged(override_of(path, True, "userspace")))
    assert set(doc.get("networks", {})) <= {"default"}, doc["networks"]
    for name, svc in doc["services"].items():
        assert not svc.get("ports") and not svc.get("networks"), f"{path.name}: service {name} leaves the bench network"


def test_the_router_images_own_config_listens_on_loopback_only():
    # used by a `docker run` of the image outside the bench (with --network host it would be the
    # host's interfaces): wider only where the user says
    text = (REPO / "images" / "router" / "zenohd.json5").read_text()
    endpoints = re.findall(r'"([a-z]+/[^"]+:\d+)"', text)
    assert endpoints and all(re.match(r"[a-z]+/(127\.0\.0\.1|\[::1\]|localhost):", e) for e in endpoints), endpoints
    assert re.search(r"multicast:\s*\{\s*enabled:\s*false", text)
