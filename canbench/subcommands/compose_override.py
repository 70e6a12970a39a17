"""canbench compose-override SCENARIO: the compose override of a scenario (canbench.compose); with
--device, for a device of your own in the bridge's place (canbench.device)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from .. import device, scenario
from ..compose import bridge_environment, compose_override


def cmd_compose_override(args) -> int:
    sc = scenario.load(args.scenario)
    dev = None
    if args.device:
        try:
            dev = device.parse(args.device)
        except ValueError as e:
            print(f"canbench compose-override: {e}", file=sys.stderr)
            return 2
        problems = device.refusals(sc, args.can_mode, args.device_restartable)
        if not args.device_canbus:
            problems.append("--device needs --device-canbus: the host directory of the hub's socket")
        if problems:
            print("\n".join(f"DEVICE={args.device}: {p}" for p in problems), file=sys.stderr)
            return 2
        if args.device_env:
            args.device_env.write_text(device.env_file(bridge_environment(sc)))
    yaml.safe_dump(compose_override(sc, args.container_path or str(args.scenario), args.viewer, args.can_mode,
                                    dev, args.device_canbus or ""), sys.stdout, sort_keys=False)
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compose-override", help="compose override: bus, bridge settings, one service per ECU")
    p.add_argument("scenario", type=Path)
    p.add_argument("--container-path", help="the scenario's path inside the containers")
    p.add_argument("--viewer", action="store_true", help="add a viewer service recording traffic.rrd")
    p.add_argument("--can-mode", choices=("userspace", "kernel"), default="userspace",
                   help="kernel: the bus container creates vcan interfaces (root with NET_ADMIN, that container only)")
    p.add_argument("--device", help="host:PORT: a device of your own in the bridge's place, the router on "
                                    "127.0.0.1:PORT (exit 2 when the scenario cannot run against one)")
    p.add_argument("--device-restartable", action="store_true",
                   help="bench-run can stop the device and start it again (DEVICE_CMD or DEVICE_HOOK)")
    p.add_argument("--device-canbus", help="the host directory bound as the hub's socket directory")
    p.add_argument("--device-env", type=Path, help="write the scenario's bridge settings here (KEY=value lines)")
    p.set_defaults(func=cmd_compose_override)
