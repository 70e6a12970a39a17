"""canbench validate SCENARIO...: check scenario files and their traces."""
from __future__ import annotations

import argparse
from pathlib import Path

from .. import validate


def cmd_validate(args) -> int:
    return validate.run(args.scenarios)


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="check scenario files and their traces")
    p.add_argument("scenarios", nargs="+", type=Path)
    p.set_defaults(func=cmd_validate)
