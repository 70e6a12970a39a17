"""canbench summarise TRACE: per-id counts, cycle times, jitter and bus load of a trace."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import authoring


def cmd_summarise(args) -> int:
    for trace in args.traces:
        print(authoring.summarise(trace, args.bitrate).table())
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("summarise", aliases=["summarize"], help="per-id summary of traces")
    p.add_argument("traces", nargs="+", type=Path)
    p.add_argument("--bitrate", type=int, default=500_000, help="for the bus load (default 500000)")
    p.set_defaults(func=cmd_summarise)
