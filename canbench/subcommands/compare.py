"""canbench compare OLD NEW: diff two runs' metrics.json; exit 1 on a regression."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import compare


def cmd_compare(args) -> int:
    old, new = compare.load_metrics(args.old), compare.load_metrics(args.new)
    rows = compare.compare(old, new, args.latency_pct, args.floor_ms, args.p99_pct)
    print(compare.render(rows, old, new))
    return 1 if any(r.regression for r in rows) else 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="diff two runs' metrics.json; exit 1 on a regression (nightly gate)")
    p.add_argument("old", type=Path, help="metrics.json or run directory of the reference run")
    p.add_argument("new", type=Path, help="metrics.json or run directory of the run to judge")
    p.add_argument("--latency-pct", type=float, default=50.0, help="p50 may grow by this %% (default 50)")
    p.add_argument("--floor-ms", type=float, default=0.05, help="smaller p50 changes are noise (default 0.05)")
    p.add_argument("--p99-pct", type=float, default=None, help="also gate p99 growth at this %%")
    p.set_defaults(func=cmd_compare)
