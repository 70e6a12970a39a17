"""canbench open [RUN]: the HTML report of a run (default reports/latest)."""
from __future__ import annotations

import argparse
import webbrowser
from pathlib import Path

from ..errors import InputError


def cmd_open(args) -> int:
    page = (args.run or Path("reports") / "latest") / "report.html"
    if not page.exists():
        raise InputError(str(page), None, "no report there (make test writes reports/<run>/report.html)")
    print(page.resolve())
    if not args.print_only:
        webbrowser.open(page.resolve().as_uri())
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("open", help="open a run's HTML report (default reports/latest)")
    p.add_argument("run", nargs="?", type=Path)
    p.add_argument("--print-only", action="store_true", help="print the path, do not start a browser")
    p.set_defaults(func=cmd_open)
