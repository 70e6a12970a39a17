"""canbench identities DIR [--scenario S] [--open]: the run's Zenoh identities and the routers'
configs with access control (canbench.identities, docs/access-control.md)."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import identities, runkeys, scenario


def cmd_identities(args) -> int:
    ros2_keys: tuple[str, ...] = ()
    ros2_domains: tuple[int, ...] = ()
    bridge_listens = False
    mode = "client"
    if args.scenario:
        sc = scenario.load(args.scenario)
        ros2_keys = tuple(runkeys.ros2_data_keys(sc))
        ros2_domains = (sc.bridge.get("ros2_domain", 0),) if sc.bridge.get("ros2_topic") else ()
        bridge_listens = sc.consumer == "bridge" or "listen" in sc.bridge
        mode = sc.bridge.get("mode", "client")
    device = (args.device_host_dir, args.device_endpoint) if args.device_endpoint else None
    names = identities.generate(args.dir, secure=not args.open, ros2_keys=ros2_keys, ros2_domains=ros2_domains,
                                bridge_listens=bridge_listens, device=device, device_mode=mode)
    print(f"identities: {len(names)} in {args.dir} ({'plain tcp, no access control' if args.open else 'mTLS + ACL'})")
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identities", help="the run's Zenoh identities (mTLS certificates) and router configs")
    p.add_argument("dir", type=Path, help="an empty directory (scripts/bench-run: build/runs/<run-id>.identities)")
    p.add_argument("--scenario", type=Path, help="the run's scenario: its ROS 2 keys, whether the bridge listens")
    p.add_argument("--open", action="store_true", help="no TLS, no ACL: plain tcp (BENCH_ACCESS=open)")
    p.add_argument("--device-endpoint", help="also an identity for a device of your own (canbench.device), "
                                             "dialling this endpoint (tls/127.0.0.1:PORT)")
    p.add_argument("--device-host-dir", default="", help="where the host holds DIR (the device's config names "
                                                         "its files there)")
    p.set_defaults(func=cmd_identities)
