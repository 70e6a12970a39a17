"""canbench summarise TRACE [--dbc F [--dbc-lenient]]: per-id counts, cycle times, jitter and bus load of a trace;
with a DBC, per message of it the statistics of each signal (count, min, max, mean, names seen)."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import authoring
from ..dbc import read_dbc
from ..errors import InputError


def cmd_summarise(args) -> int:
    if args.dbc_lenient and not args.dbc:
        raise InputError("--dbc-lenient", None, "reads the DBC --dbc names: give --dbc too")
    if args.dbc:
        read_dbc(args.dbc, args.dbc_lenient)  # refused before any table is printed
    for trace in args.traces:
        print(authoring.summarise(trace, args.bitrate).table())
        if args.dbc:
            print(authoring.summarise_signals(trace, args.dbc, args.dbc_lenient).table())
    return 0


def bitrate(text: str) -> int:
    """--bitrate: bit/s above 0 (the bus load is bits over bitrate)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the bus's bit/s, a whole number above 0 (e.g. 500000)")
    return value


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("summarise", aliases=["summarize"], help="per-id summary of traces")
    p.add_argument("traces", nargs="+", type=Path)
    p.add_argument("--bitrate", type=bitrate, default=500_000, help="for the bus load (default 500000)")
    p.add_argument("--dbc", type=Path, help="also per-message signal statistics, decoded with this DBC (cantools)")
    p.add_argument("--dbc-lenient", action="store_true",
                   help="read a DBC strict reading refuses (signals that overlap or pass their message's end, "
                        "or that cantools reads wrong: docs/bench.md) "
                        "as written, each such message signal by signal")
    p.set_defaults(func=cmd_summarise)
