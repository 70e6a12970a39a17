"""canbench command line.

  canbench validate SCENARIO...            check scenario files and their traces
  canbench compose-override SCENARIO       compose override: bus, bridge settings, one service per ECU
  canbench ecu --scenario S --name N ...   run one emulated ECU (inside its container)
  canbench gen-trace --kind K --out F      write a synthetic trace (powertrain, mixed, burst)

Errors are one line (file:line where it applies); --debug shows the traceback.
Exit codes: 0 ok, 1 run failure, 2 bad input."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from . import ecu, scenario, tracegen
from .errors import BenchError
from .trace import read_trace


def cmd_validate(args) -> int:
    for path in args.scenarios:
        sc = scenario.load(path)
        for e in sc.ecus:
            if e.trace:
                read_trace(e.trace, None)
        print(f"{path}: ok ({len(sc.ecus)} ECUs on {', '.join(sc.bus_names)})")
    return 0


BRIDGE_ENV = {  # scenario bridge key -> the bridge's environment variable (its Kconfig name)
    "mode": "ZENOH_NODE_MODE", "publish_period_ms": "ZENOH_PUBLISH_PERIOD_MS",
    "batch_max_frames": "ZENOH_BATCH_MAX_FRAMES", "allow_ids": "ZENOH_NODE_ALLOW_IDS",
    "deny_ids": "ZENOH_NODE_DENY_IDS", "rx_congestion": "ZENOH_RX_CONGESTION", "rx_priority": "ZENOH_RX_PRIORITY",
    "listen": "ZENOH_LISTEN",
}
BRIDGE_LISTEN = "tcp/0.0.0.0:7448"  # where a consumer reaches the bridge directly (topology consumer: bridge)


def bus_spec(bus: dict) -> str:
    opts = [f"{k}={bus[k]}" for k in ("bitrate", "stuffing") if k in bus]
    return bus["name"] + (":" + ",".join(opts) if opts else "")


def compose_override(sc: scenario.Scenario, scenario_in_container: str) -> dict:
    bridge_env = {"ZENOH_NODE_CAN": ",".join(sc.bus_names), "ZENOH_PUBLISH_PERIOD_MS": "0"}
    bridge_env.update({env: str(sc.bridge[key]) for key, env in BRIDGE_ENV.items() if key in sc.bridge})
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
            "command": ["--config", "/etc/zenohd/zenohd.json5"],
            "volumes": ["./images/router/zenohd-far.json5:/etc/zenohd/zenohd.json5:ro"],
            "depends_on": {"router": {"condition": "service_healthy"}},
            "healthcheck": {"test": ["CMD", "bash", "-c", "</dev/tcp/127.0.0.1/7447"], "interval": "1s",
                            "timeout": "2s", "retries": 60},
        }
        orchestrator_env["BENCH_CONSUMER"] = "tcp/router2:7447"
    for e in sc.ecus:
        services[f"ecu-{e.name}"] = {
            "image": "canbench/ecu:${BENCH_TAG:-latest}",
            "network_mode": "service:bus",
            "depends_on": {"bus": {"condition": "service_healthy"}, "router": {"condition": "service_healthy"}},
            "environment": ["BENCH_CAN_MODE", "RUN_ID"],
            "user": "${BENCH_UID:-0}:${BENCH_GID:-0}",
            "volumes": ["canbus:/run/ucan", "./reports:/reports", "${SCENARIO_DIR:-./scenarios}:/scenarios:ro"],
            "command": ["canbench", "ecu", "--scenario", scenario_in_container, "--name", e.name,
                        "--run-id", "${RUN_ID}", "--run-dir", "/reports/${RUN_ID}", "--router", "tcp/router:7447"],
        }
    return {"services": services}


def cmd_compose_override(args) -> int:
    sc = scenario.load(args.scenario)
    yaml.safe_dump(compose_override(sc, args.container_path or str(args.scenario)), sys.stdout, sort_keys=False)
    return 0


def cmd_ecu(args) -> int:
    sc = scenario.load(args.scenario)
    run_dir = Path(args.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    summary = ecu.run(sc, args.name, args.run_id, run_dir, args.router, args.timeout)
    print(f"ecu {args.name}: sent {summary['sent']} frames, send-time error p50 "
          f"{summary['fidelity_ms']['p50']} ms p99 {summary['fidelity_ms']['p99']} ms")
    return 0


def cmd_gen_trace(args) -> int:
    print(tracegen.generate_file(args.kind, args.seconds, args.frames, args.out))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="canbench", description=__doc__.split("\n")[0])
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("validate", help="check scenario files and their traces")
    p.add_argument("scenarios", nargs="+", type=Path)
    p.set_defaults(func=cmd_validate)
    p = sub.add_parser("compose-override", help="compose override: bus, bridge settings, one service per ECU")
    p.add_argument("scenario", type=Path)
    p.add_argument("--container-path", help="the scenario's path inside the containers")
    p.set_defaults(func=cmd_compose_override)
    p = sub.add_parser("ecu", help="run one emulated ECU")
    p.add_argument("--scenario", type=Path, required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--run-id", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--router", default="tcp/router:7447")
    p.add_argument("--timeout", type=float, default=120, help="seconds to wait for the capture to be ready")
    p.set_defaults(func=cmd_ecu)
    p = sub.add_parser("gen-trace", help="write a synthetic trace (candump -L): powertrain, mixed, burst")
    tracegen.add_arguments(p)
    p.set_defaults(func=cmd_gen_trace)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except BenchError as e:
        if args.debug:
            raise
        print(f"canbench: {e}", file=sys.stderr)
        return e.exit_code
    except (TimeoutError, OSError) as e:
        if args.debug:
            raise
        print(f"canbench: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
