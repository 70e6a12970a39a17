"""canbench run SCENARIO: run one scenario in compose (scripts/bench-run)."""
from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

from .. import scenario
from ..errors import InputError

REPO = Path(__file__).resolve().parents[2]


def cmd_run(args) -> int:
    script = REPO / "scripts" / "bench-run"
    if not script.exists():
        raise InputError(str(script), None, "canbench run needs the bench's repository (scripts/bench-run)")
    scenario.load(args.scenario)
    return subprocess.call([str(script), str(args.scenario)], cwd=REPO)


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run one scenario in compose (scripts/bench-run)")
    p.add_argument("scenario", type=Path)
    p.set_defaults(func=cmd_run)
