"""canbench command line.

  canbench run SCENARIO                    run one scenario in compose (scripts/bench-run)
  canbench open [RUN]                      the HTML report of a run (default reports/latest)
  canbench view [--auto-subscribe ...]     bridges and ROS 2 topics on a Zenoh network, in Rerun
  canbench compare OLD NEW                 diff two runs' metrics.json; exit 1 on a regression
  canbench summarise TRACE                 per-id counts, cycle times, jitter and bus load of a trace
  canbench scaffold TRACE --name N         a scenario replaying a trace, gates derived from it
  canbench validate SCENARIO...            check scenario files and their traces
  canbench compose-override SCENARIO       compose override: bus, bridge settings, one service per ECU
  canbench ecu --scenario S --name N ...   run one emulated ECU (inside its container)
  canbench gen-trace --kind K --out F      write a synthetic trace (powertrain, mixed, burst)
  canbench suite plan|summary ...          make test's shards and its suite summary (scripts/bench-suite)

Errors are one line (file:line where it applies); --debug shows the traceback.
Exit codes: 0 ok, 1 run failure, 2 bad input."""
from __future__ import annotations

import argparse
import subprocess
import sys
import webbrowser
from pathlib import Path

import yaml

from . import authoring, compare, ecu, faults, scenario, suite, tracegen, validate
from .errors import BenchError, InputError

REPO = Path(__file__).resolve().parents[1]


def _add_view_arguments(p) -> None:
    from .viewer_args import add_arguments
    add_arguments(p)


def cmd_validate(args) -> int:
    return validate.run(args.scenarios)


BRIDGE_ENV = {  # scenario bridge key -> the bridge's environment variable (its Kconfig name)
    "mode": "ZENOH_NODE_MODE", "publish_period_ms": "ZENOH_PUBLISH_PERIOD_MS",
    "batch_max_frames": "ZENOH_BATCH_MAX_FRAMES", "allow_ids": "ZENOH_NODE_ALLOW_IDS",
    "deny_ids": "ZENOH_NODE_DENY_IDS", "rx_congestion": "ZENOH_RX_CONGESTION", "rx_priority": "ZENOH_RX_PRIORITY",
    "listen": "ZENOH_LISTEN", "ros2_topic": "ZENOH_ROS2_TOPIC", "ros2_domain": "ZENOH_ROS2_DOMAIN",
}
BRIDGE_LISTEN = "tcp/0.0.0.0:7448"  # where a consumer reaches the bridge directly (topology consumer: bridge)


def bus_spec(bus: dict) -> str:
    opts = [f"{k}={bus[k]}" for k in ("bitrate", "stuffing") if k in bus]
    return bus["name"] + (":" + ",".join(opts) if opts else "")


def compose_override(sc: scenario.Scenario, scenario_in_container: str, viewer: bool = False) -> dict:
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


def cmd_compose_override(args) -> int:
    sc = scenario.load(args.scenario)
    yaml.safe_dump(compose_override(sc, args.container_path or str(args.scenario), args.viewer), sys.stdout,
                   sort_keys=False)
    return 0


def cmd_ecu(args) -> int:
    sc = scenario.load(args.scenario)
    run_dir = Path(args.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    summary = ecu.run(sc, args.name, args.run_id, run_dir, args.router, args.timeout)
    timing = summary.get("fidelity_ms") or summary.get("turnaround_ms") or {}
    what = "turnaround" if "turnaround_ms" in summary else "send-time error"
    print(f"ecu {args.name} ({summary['role']}): sent {summary['sent']} frames, {what} p50 "
          f"{timing.get('p50')} ms p99 {timing.get('p99')} ms")
    return 0


def cmd_gen_trace(args) -> int:
    print(tracegen.generate_file(args.kind, args.seconds, args.frames, args.out))
    return 0


def cmd_compare(args) -> int:
    old, new = compare.load_metrics(args.old), compare.load_metrics(args.new)
    rows = compare.compare(old, new, args.latency_pct, args.floor_ms, args.p99_pct)
    print(compare.render(rows, old, new))
    return 1 if any(r.regression for r in rows) else 0


def cmd_summarise(args) -> int:
    for trace in args.traces:
        print(authoring.summarise(trace, args.bitrate).table())
    return 0


def cmd_scaffold(args) -> int:
    out = args.out or Path("scenarios") / f"{args.name}.yaml"
    if out.exists() and not args.force:
        raise InputError(str(out), None, "exists already (--force to overwrite)")
    text = authoring.scaffold(args.trace, args.name, out, args.bitrate)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    scenario.load(out)  # what we write must be valid
    print(f"{out}: written; review its gates, then: make test SCENARIO={out}")
    return 0


def cmd_run(args) -> int:
    script = REPO / "scripts" / "bench-run"
    if not script.exists():
        raise InputError(str(script), None, "canbench run needs the bench's repository (scripts/bench-run)")
    scenario.load(args.scenario)
    return subprocess.call([str(script), str(args.scenario)], cwd=REPO)


def cmd_open(args) -> int:
    page = (args.run or Path("reports") / "latest") / "report.html"
    if not page.exists():
        raise InputError(str(page), None, "no report there (make test writes reports/<run>/report.html)")
    print(page.resolve())
    if not args.print_only:
        webbrowser.open(page.resolve().as_uri())
    return 0


def cmd_view(args) -> int:
    from . import viewer  # Rerun is only needed here
    return viewer.run(args)


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
    p.add_argument("--viewer", action="store_true", help="add a viewer service recording traffic.rrd")
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
    p = sub.add_parser("compare", help="diff two runs' metrics.json; exit 1 on a regression (nightly gate)")
    p.add_argument("old", type=Path, help="metrics.json or run directory of the reference run")
    p.add_argument("new", type=Path, help="metrics.json or run directory of the run to judge")
    p.add_argument("--latency-pct", type=float, default=50.0, help="p50 may grow by this %% (default 50)")
    p.add_argument("--floor-ms", type=float, default=0.05, help="smaller p50 changes are noise (default 0.05)")
    p.add_argument("--p99-pct", type=float, default=None, help="also gate p99 growth at this %%")
    p.set_defaults(func=cmd_compare)
    p = sub.add_parser("summarise", aliases=["summarize"], help="per-id summary of traces")
    p.add_argument("traces", nargs="+", type=Path)
    p.add_argument("--bitrate", type=int, default=500_000, help="for the bus load (default 500000)")
    p.set_defaults(func=cmd_summarise)
    p = sub.add_parser("scaffold", help="write a scenario replaying a trace")
    p.add_argument("trace", type=Path)
    p.add_argument("--name", required=True, help="scenario name (lowercase, digits, - and _)")
    p.add_argument("--out", type=Path, help="default scenarios/<name>.yaml")
    p.add_argument("--bitrate", type=int, default=500_000)
    p.add_argument("--force", action="store_true")
    p.set_defaults(func=cmd_scaffold)
    p = sub.add_parser("run", help="run one scenario in compose (scripts/bench-run)")
    p.add_argument("scenario", type=Path)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("open", help="open a run's HTML report (default reports/latest)")
    p.add_argument("run", nargs="?", type=Path)
    p.add_argument("--print-only", action="store_true", help="print the path, do not start a browser")
    p.set_defaults(func=cmd_open)
    p = sub.add_parser("suite", help="a make test suite: its shard plan, its summary (scripts/bench-suite)")
    suite.add_arguments(p)
    p.set_defaults(func=suite.main)
    p = sub.add_parser("view", help="bridges and ROS 2 topics on a Zenoh network (or a recording) in Rerun")
    _add_view_arguments(p)
    p.set_defaults(func=cmd_view)
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
