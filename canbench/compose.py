"""The compose override of one scenario (`canbench compose-override`, scripts/bench-run): the bus's
interfaces, the bridge's settings as its environment, one service per emulated ECU, and what a
topology, a recording viewer, fault steps or the security scenario's probes add. Every service it
adds runs as compose.yaml's do (HARDENING: the bench's user, no capabilities, no new privileges,
a read-only root file system) with its own identity from the run's identities directory
(canbench.identities, docs/access-control.md)."""
from __future__ import annotations

from pathlib import Path

from . import faults, scenario, security
from .device import Device
from .device import override as device_override
from .identities import PORT

# scenario bridge key -> the bridge's environment variable: the schema's x-env of each key
# (tests/unit/test_bridge_options.py holds it to the bridge's option table and Kconfig)
BRIDGE_ENV = {key: spec["x-env"] for key, spec in scenario.schema()["properties"]["bridge"]["properties"].items()}
# where a consumer reaches the bridge directly (topology consumer: bridge): the orchestrator shares
# the bridge's network namespace, so loopback; anything wider only where the scenario says
# (bridge.listen). ${BENCH_ZENOH_SCHEME}: tls, or tcp without access control (BENCH_ACCESS=open)
SCHEME = "${BENCH_ZENOH_SCHEME:-tls}"
BRIDGE_LISTEN = f"{SCHEME}/127.0.0.1:7448"
ROUTER = f"{SCHEME}/router:7447"
USER = "${BENCH_UID:-10000}:${BENCH_GID:-10000}"
HARDENING = {"user": USER, "cap_drop": ["ALL"], "security_opt": ["no-new-privileges:true"], "read_only": True}
# The bus and the emulated ECUs are the bench's reference: when the services share too few cores,
# their cgroups' CPU weight (4x Docker's 1024) wakes them first, so the traffic keeps to its trace
# (validity: invalid: emulator) and a scheduling delay lands on the bridge under test, as it would
# on its own hardware, not on the stimulus. Needs no capability; compose.yaml sets it on the bus.
REFERENCE_CPU_SHARES = 4096
IDENTITIES = "${BENCH_IDENTITIES:?the run's identities directory (scripts/bench-run makes it)}"


def identity(name: str, mount: str = "/run/zenoh") -> str:
    """The volume of one identity's directory (certificate, key, Zenoh config), read-only."""
    return f"{IDENTITIES}/{name}:{mount}:ro"


def hardened(service: dict, tmp: bool = False) -> dict:
    """service with HARDENING (and a /tmp tmpfs, HOME there, for Python services)."""
    out = {**service, **{k: list(v) if isinstance(v, list) else v for k, v in HARDENING.items()}}
    if tmp:
        out["tmpfs"] = ["/tmp"]
        out["environment"] = [*out.get("environment", []), "HOME=/tmp", "MPLCONFIGDIR=/tmp/matplotlib"]
    return out


def bus_spec(bus: dict) -> str:
    opts = [f"{k}={bus[k]}" for k in ("bitrate", "stuffing") if k in bus]
    return bus["name"] + (":" + ",".join(opts) if opts else "")


def bridge_environment(sc: scenario.Scenario) -> dict[str, str]:
    """The scenario's bridge settings as the bridge's environment variables."""
    bridge_env = {"ZENOH_NODE_CAN": ",".join(sc.bus_names), "ZENOH_PUBLISH_PERIOD_MS": "0"}
    bridge_env.update({env: str(sc.bridge[key]).lower() if isinstance(sc.bridge[key], bool) else str(sc.bridge[key])
                       for key, env in BRIDGE_ENV.items() if key in sc.bridge})  # a YAML true as the bridge's "true"
    bridge_env.setdefault(BRIDGE_ENV["tx_max_age_ms"], str(sc.tx_max_age_ms))  # on by default in the bench
    return bridge_env


def compose_override(sc: scenario.Scenario, scenario_in_container: str, viewer: bool = False,
                     can_mode: str = "userspace", device: Device | None = None, canbus_dir: str = "") -> dict:
    """device: a device of your own in the bridge's place (canbench.device), its bus in canbus_dir."""
    bridge_env = bridge_environment(sc)
    orchestrator_env = {"SCENARIO": scenario_in_container}
    services: dict = {
        "bus": {"environment": {"BENCH_CAN_IFACES": " ".join(bus_spec(b) for b in sc.buses)}},
        "bridge": {"environment": bridge_env},
        "orchestrator": {"environment": orchestrator_env},
    }
    if can_mode == "kernel":
        # kernel vcan: `ip link add` in the bus's namespace needs root with NET_ADMIN (that
        # container only; it then only keeps the namespace: tail -f /dev/null)
        services["bus"] |= {"user": "0:0", "cap_add": ["NET_ADMIN"]}
    if sc.consumer == "bridge":
        bridge_env.setdefault("ZENOH_LISTEN", BRIDGE_LISTEN)
        # the orchestrator shares the bus's network namespace with the bridge
        port = bridge_env["ZENOH_LISTEN"].split(",")[0].rsplit(":", 1)[1]
        orchestrator_env["BENCH_CONSUMER"] = f"{SCHEME}/127.0.0.1:{port}"
    elif sc.consumer == "far_router":
        # its config (canbench.identities): connects to the bench router as identity router2
        services["router2"] = hardened({
            "image": "${ROUTER_IMAGE:-canbench/router:latest}",
            "init": True,
            "command": ["--config", "/run/zenoh/zenohd.json5"],
            "volumes": [identity("router2")],
            "depends_on": {"router": {"condition": "service_healthy"}},
            "healthcheck": {"test": ["CMD", "bash", "-c", "</dev/tcp/127.0.0.1/7447"], "interval": "1s",
                            "timeout": "2s", "retries": 60},
        })
        orchestrator_env["BENCH_CONSUMER"] = f"{SCHEME}/router2:7447"
    if viewer:
        # `canbench view --save` records the run next to its reports (make test VIEWER=1)
        def inside(p: Path) -> str:  # a file of the scenario's directory, as the container mounts it
            return str(Path(scenario_in_container).parent / p.relative_to(sc.path.resolve().parent))
        dbc = ["--dbc", inside(sc.dbc)] if sc.dbc else []
        # each bus with a DBC of its own (buses[].dbc) decoded with it; the others with the top-level one
        for bus, bus_dbc in sc.bus_dbcs.items():
            if bus_dbc != sc.dbc:
                dbc += ["--bus-dbc", f"{bus}={inside(bus_dbc)}"]
        if dbc and sc.raw.get("dbc_strict") is False:  # the scenario's DBCs as written, as its checks read them
            dbc.append("--dbc-lenient")
        services["viewer"] = hardened({
            "image": "canbench/orchestrator:${BENCH_TAG:-latest}",
            "network_mode": "service:bus",
            "depends_on": {"router": {"condition": "service_healthy"}},
            "environment": ["ZENOH_CONFIG=/run/zenoh/zenoh.json5"],
            "volumes": ["./reports:/reports", "${SCENARIO_DIR:-./scenarios}:/scenarios:ro", identity("viewer")],
            "command": ["canbench", "view", "--zenoh-connect", ROUTER, "--auto-subscribe", *dbc,
                        "--save", "/reports/${RUN_ID}/traffic.rrd"],
        }, tmp=True)
        orchestrator_env["BENCH_VIEWER"] = "1"
    partitioned = any(f.action == "partition" for f in sc.faults)
    if partitioned:
        # the bridge gets a listener of its own on the router: the partition drops that port only
        services["router"] = {"command": ["--config", "/run/zenoh/zenohd.json5", "--listen", f"{SCHEME}/0.0.0.0:7447",
                                          "--listen", f"{SCHEME}/0.0.0.0:{faults.PARTITION_PORT}"]}
        bridge_env["ZENOH_ROUTER_ADDRESS"] = f"{SCHEME}/router:{faults.PARTITION_PORT}"
    if sc.faults:
        # fault steps drive Docker's API: the socket, for the orchestrator only (docs/faults.md); whoever
        # holds it controls the host's Docker, so only scenarios with fault steps mount it
        services["orchestrator"]["volumes"] = ["/var/run/docker.sock:/var/run/docker.sock"]
        services["orchestrator"]["group_add"] = ["${DOCKER_GID:-0}"]
    for e in sc.ecus:
        services[f"ecu-{e.name}"] = hardened({
            "image": "canbench/ecu:${BENCH_TAG:-latest}",
            "network_mode": "service:bus",
            "cpu_shares": REFERENCE_CPU_SHARES,
            "depends_on": {"bus": {"condition": "service_healthy"}, "router": {"condition": "service_healthy"}},
            "environment": ["BENCH_CAN_MODE", "RUN_ID", "ZENOH_CONFIG=/run/zenoh/zenoh.json5"],
            "volumes": ["canbus:/run/ucan", "./reports:/reports", "${SCENARIO_DIR:-./scenarios}:/scenarios:ro",
                        identity("ecu")],
            # bench-run does not expect an ECU that a fault step kills to exit cleanly
            "labels": {"bench.fault-target": str(any(f.target == e.name for f in sc.faults)).lower()},
            "command": ["canbench", "ecu", "--scenario", scenario_in_container, "--name", e.name,
                        "--run-id", "${RUN_ID}", "--run-dir", "/reports/${RUN_ID}", "--router", ROUTER,
                        # the capture comes after the bridge's token: as long as the run waits for it, and then some
                        "--timeout", "${BENCH_ECU_WAIT_S:-120}"],
        }, tmp=True)
    services.update(probe_services(sc))
    out: dict = {"services": services}
    if device:
        # a partition drops the bridge's own listener: the device reaches the router there
        extra = device_override(device, canbus_dir, faults.PARTITION_PORT if partitioned else PORT)
        services["router"] = {**services.get("router", {}), **extra["services"]["router"]}
        out["volumes"] = extra["volumes"]
    return out


def probe_services(sc: scenario.Scenario) -> dict:
    """The security scenario's probes (canbench.security): containers on the bench network (not the
    bus's namespace: no CAN), each with the credentials it is named for, and a real bridge with a
    certificate of another CA."""
    sec = security.spec(sc)
    if not sec:
        return {}
    services: dict = {}
    frames = str(sec.get("frames", 20))
    for name in sec.get("probes", security.PROBES):
        services[f"probe-{name}"] = hardened({
            "image": "canbench/ecu:${BENCH_TAG:-latest}",
            "depends_on": {"router": {"condition": "service_healthy"}},
            "environment": ["BENCH_CAN_MODE=none"],  # no bus here: bench-can preloads nothing
            "volumes": ["./reports:/reports", identity(name)],
            "command": ["canbench", "probe", name, "--router", ROUTER, "--run-id", "${RUN_ID}", "--run-dir",
                        "/reports/${RUN_ID}", "--frames", frames, "--zenoh-config", "/run/zenoh/zenoh.json5"],
        }, tmp=True)
        if name == "rogue-bridge":
            # the bridge itself with that certificate, on the bus: were it let in, its token would show
            # and the probes' commands would have a second way onto the bus
            services["bridge-rogue"] = hardened({
                "image": "canbench/bridge:${BENCH_TAG:-latest}",
                "network_mode": "service:bus",
                "depends_on": {"bus": {"condition": "service_healthy"}, "router": {"condition": "service_healthy"}},
                "environment": ["BENCH_CAN_MODE", f"ZENOH_ROUTER_ADDRESS={ROUTER}",
                                "ZENOH_CONFIG=/run/zenoh/zenoh.json5", f"ZENOH_NODE_NAME={security.ROGUE_NODE}",
                                f"ZENOH_NODE_CAN={','.join(sc.bus_names)}"],
                "volumes": ["canbus:/run/ucan", identity("rogue-bridge")],
            })
    return services
