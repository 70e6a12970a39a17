"""Command-line arguments of `canbench view` (kept apart so the CLI does not import Rerun)."""
from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def ros_domain(text: str) -> int:
    """--ros-domain: a ROS_DOMAIN_ID, 0 to 232 (rmw_zenoh's range, as ROS 2's)."""
    if not (text.isascii() and text.isdigit() and int(text) <= 232):
        raise argparse.ArgumentTypeError(f"{text!r}: a ROS_DOMAIN_ID is a whole number from 0 to 232")
    return int(text)


def add_arguments(p) -> None:
    p.add_argument("source", nargs="?", type=Path, help="a bench recording (.mcap) instead of a live network")
    p.add_argument("--zenoh-mode", choices=["client", "peer"], default="client")
    p.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help=f"repeatable (default {DEFAULT_ENDPOINT})")
    p.add_argument("--auto-subscribe", action="store_true", help="every discovered topic with a logger")
    p.add_argument("-t", "--topic", action="append", default=[], help="a ROS 2 topic to subscribe (repeatable)")
    p.add_argument("--ros-domain", type=ros_domain, metavar="ID",
                   help="only this ROS_DOMAIN_ID (default: every domain; one other than 0 at ros2/domain<ID>/...)")
    p.add_argument("--urdf", type=Path, help="a robot or vehicle model (URDF) shown with the live data")
    p.add_argument("--dbc", type=Path, help="decode CAN signals with this DBC (cantools)")
    p.add_argument("--bus-dbc", action="append", default=[], metavar="BUS=FILE",
                   help="decode this bus's frames with its own DBC instead of --dbc (repeatable; the bus "
                        "as its keys name it: <prefix>/<bus>/rx, or a one-bus bridge's token)")
    p.add_argument("--dbc-lenient", action="store_true",
                   help="read DBCs strict reading refuses (signals that overlap or pass their message's end, "
                        "or that cantools reads wrong: docs/bench.md) "
                        "as written, each such message signal by signal")
    p.add_argument("--save", type=Path, help="write an .rrd file instead of spawning the Rerun viewer")
    p.add_argument("--duration", type=float, default=0, help="stop after this many seconds (0: until Ctrl-C)")
