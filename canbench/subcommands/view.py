"""canbench view ...: bridges and ROS 2 topics on a Zenoh network, in Rerun."""
from __future__ import annotations

import argparse

from .. import viewer_args


def cmd_view(args) -> int:
    from .. import viewer  # Rerun is only needed here
    return viewer.run(args)


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="bridges and ROS 2 topics on a Zenoh network (or a recording) in Rerun")
    viewer_args.add_arguments(p)
    p.set_defaults(func=cmd_view)
