"""canbench suite plan|summary ...: make test's shards and its suite summary (scripts/bench-suite)."""
from __future__ import annotations

import argparse

from .. import suite


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("suite", help="a make test suite: its shard plan, its summary (scripts/bench-suite)")
    suite.add_arguments(p)
    p.set_defaults(func=suite.main)
