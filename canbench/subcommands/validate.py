"""canbench validate SCENARIO...: check scenario files and their traces."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import validate


def cmd_validate(args) -> int:
    return validate.run(args.scenarios)


BRIDGE_ENV = {  # scenario bridge key -> the bridge's environment variable (its Kconfig name)
    "mode": "ZENOH_NODE_MODE", "publish_period_ms": "ZENOH_PUBLISH_PERIOD_MS",
    "batch_max_frames": "ZENOH_BATCH_MAX_FRAMES", "allow_ids": "ZENOH_NODE_ALLOW_IDS",
    "deny_ids": "ZENOH_NODE_DENY_IDS", "rx_congestion": "ZENOH_RX_CONGESTION", "rx_priority": "ZENOH_RX_PRIORITY",
    "listen": "ZENOH_LISTEN", "ros2_topic": "ZENOH_ROS2_TOPIC", "ros2_domain": "ZENOH_ROS2_DOMAIN",
}
BRIDGE_LISTEN = "tcp/0.0.0.0:7448"  # where a consumer reaches the bridge directly (topology consumer: bridge)


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check scenario files and their traces")
    p.add_argument("scenarios", nargs="+", type=Path)
    p.set_defaults(func=cmd_validate)
