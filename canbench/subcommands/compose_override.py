"""canbench compose-override SCENARIO: the compose override of a scenario (canbench.compose)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from .. import scenario
from ..compose import compose_override


def cmd_compose_override(args) -> int:
    sc = scenario.load(args.scenario)
    yaml.safe_dump(compose_override(sc, args.container_path or str(args.scenario), args.viewer, args.can_mode),
                   sys.stdout, sort_keys=False)
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compose-override", help="compose override: bus, bridge settings, one service per ECU")
    p.add_argument("scenario", type=Path)
    p.add_argument("--container-path", help="the scenario's path inside the containers")
    p.add_argument("--viewer", action="store_true", help="add a viewer service recording traffic.rrd")
    p.add_argument("--can-mode", choices=("userspace", "kernel"), default="userspace",
                   help="kernel: the bus container creates vcan interfaces (root with NET_ADMIN, that container only)")
    p.set_defaults(func=cmd_compose_override)
