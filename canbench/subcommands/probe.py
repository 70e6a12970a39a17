"""canbench probe NAME --router EP ...: one of the security scenario's probes (canbench.security)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from .. import security


def cmd_probe(args) -> int:
    run_dir = Path(args.run_dir)
    result = security.probe(args.name, args.router, args.run_id, run_dir, args.frames,
                            config_file=args.zenoh_config if args.zenoh_config and Path(args.zenoh_config).exists()
                            else None)
    print(f"probe {args.name}: " + json.dumps(result))
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("probe", help="a security probe: try to put commands with the given credentials")
    p.add_argument("name", choices=security.PROBES)
    p.add_argument("--router", required=True)
    p.add_argument("--run-id", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--zenoh-config", help="the probe's credentials (a Zenoh config file)")
    p.set_defaults(func=cmd_probe)
