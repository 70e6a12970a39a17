"""The compose override of one scenario (`canbench compose-override`, scripts/bench-run): the bus's
interfaces, the bridge's settings as its environment, one service per emulated ECU, and what a
topology, a recording viewer or fault steps add."""
from __future__ import annotations

from pathlib import Path

from . import faults, scenario

# scenario bridge key -> the bridge's environment variable: the schema's x-env of each key
# (tests/unit/test_bridge_options.py holds it to the bridge's option table and Kconfig)
BRIDGE_ENV = {key: spec["x-env"] for key, spec in scenario.schema()["properties"]["bridge"]["properties"].items()}
BRIDGE_LISTEN = "tcp/0.0.0.0:7448"  # where a consumer reaches the bridge directly (topology consumer: bridge)


def bus_spec(bus: dict) -> str:
    opts = [f"{k}={bus[k]}" for k in ("bitrate", "stuffing") if k in bus]
    return bus["name"] + (":" + ",".join(opts) if opts else "")


def compose_override(sc: scenario.Scenario, scenario_in_container: str, viewer: bool = False) -> dict:
    bridge_env = {"ZENOH_NODE_CAN": ",".join(sc.bus_names), "ZENOH_PUBLISH_PERIOD_MS": "0"}
    bridge_env.update({env: str(sc.bridge[key]) for key, env in BRIDGE_ENV.items() if key in sc.bridge})
    bridge_env.setdefault(BRIDGE_ENV["tx_max_age_ms"], str(sc.tx_max_age_ms))  # on by default in the bench
    orchestrator_env = {"SCENARIO": scenario_in_container}
    services: dict = {
        "bus": {"environment": {"BENCH_CAN_IFACES": " ".join(bus_spec(b) for b in sc.buses)}},
        "bridge": {"environment": bridge_env},
        "orchestrator": {"environment": orchestrator_env},
    }
    if sc.consumer == "bridge":
        bridge_env.setdefault("ZENOH_LISTEN", BRIDGE_LISTEN)
        # the orchestrator shares the bus's network namespace with the bridge
        port = bridge_env["ZENOH_LISTEN"].split(",")[0].rsplit(":", 1)[1]
        orchestrator_env["BENCH_CONSUMER"] = f"tcp/127.0.0.1:{port}"
    elif sc.consumer == "far_router":
        services["router2"] = {
            "image": "${ROUTER_IMAGE:-canbench/router:latest}",
            "init": True,
            "command": ["--config", "/etc/zenohd/zenohd.json5"],
            "volumes": ["./images/router/zenohd-far.json5:/etc/zenohd/zenohd.json5:ro"],
            "depends_on": {"router": {"condition": "service_healthy"}},
            "healthcheck": {"test": ["CMD", "bash", "-c", "</dev/tcp/127.0.0.1/7447"], "interval": "1s",
                            "timeout": "2s", "retries": 60},
        }
        orchestrator_env["BENCH_CONSUMER"] = "tcp/router2:7447"
    if viewer:
        # `canbench view --save` records the run next to its reports (make test VIEWER=1)
        dbc = ["--dbc", str(Path(scenario_in_container).parent / sc.dbc.relative_to(sc.path.parent))] if sc.dbc else []
        services["viewer"] = {
            "image": "canbench/orchestrator:${BENCH_TAG:-latest}",
            "network_mode": "service:bus",
            "depends_on": {"router": {"condition": "service_healthy"}},
            "user": "${BENCH_UID:-0}:${BENCH_GID:-0}",
            "volumes": ["./reports:/reports", "${SCENARIO_DIR:-./scenarios}:/scenarios:ro"],
            "command": ["canbench", "view", "--zenoh-connect", "tcp/router:7447", "--auto-subscribe", *dbc,
                        "--save", "/reports/${RUN_ID}/traffic.rrd"],
        }
        orchestrator_env["BENCH_VIEWER"] = "1"
    if any(f.action == "partition" for f in sc.faults):
        # the bridge gets a listener of its own on the router: the partition drops that port only
        services["router"] = {"command": ["--config", "/etc/zenohd/zenohd.json5", "--listen", "tcp/0.0.0.0:7447",
                                          "--listen", f"tcp/0.0.0.0:{faults.PARTITION_PORT}"]}
        bridge_env["ZENOH_ROUTER_ADDRESS"] = f"tcp/router:{faults.PARTITION_PORT}"
    if sc.faults:
        # fault steps drive Docker's API: the socket, for the orchestrator only (docs/faults.md)
        services["orchestrator"]["volumes"] = ["/var/run/docker.sock:/var/run/docker.sock"]
        services["orchestrator"]["group_add"] = ["${DOCKER_GID:-0}"]
    for e in sc.ecus:
        services[f"ecu-{e.name}"] = {
            "image": "canbench/ecu:${BENCH_TAG:-latest}",
            "network_mode": "service:bus",
            "depends_on": {"bus": {"condition": "service_healthy"}, "router": {"condition": "service_healthy"}},
            "environment": ["BENCH_CAN_MODE", "RUN_ID"],
            "user": "${BENCH_UID:-0}:${BENCH_GID:-0}",
            "volumes": ["canbus:/run/ucan", "./reports:/reports", "${SCENARIO_DIR:-./scenarios}:/scenarios:ro"],
            # bench-run does not expect an ECU that a fault step kills to exit cleanly
            "labels": {"bench.fault-target": str(any(f.target == e.name for f in sc.faults)).lower()},
            "command": ["canbench", "ecu", "--scenario", scenario_in_container, "--name", e.name,
                        "--run-id", "${RUN_ID}", "--run-dir", "/reports/${RUN_ID}", "--router", "tcp/router:7447"],
        }
    return {"services": services}
