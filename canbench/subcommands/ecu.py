"""canbench ecu --scenario S --name N ...: run one emulated ECU (inside its container)."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import ecu, scenario


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


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ecu", help="run one emulated ECU")
    p.add_argument("--scenario", type=Path, required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--run-id", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--router", default="tcp/127.0.0.1:7447",
                   help="the bench router (compose passes its service's; loopback unless told)")
    p.add_argument("--timeout", type=float, default=120, help="seconds to wait for the capture to be ready")
    p.set_defaults(func=cmd_ecu)
