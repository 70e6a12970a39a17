"""canbench gen-trace --kind K --out F: write a synthetic trace (powertrain, mixed, burst)."""
from __future__ import annotations

import argparse

from .. import tracegen


def cmd_gen_trace(args) -> int:
    print(tracegen.generate_file(args.kind, args.seconds, args.frames, args.out))
    return 0


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gen-trace", help="write a synthetic trace (candump -L): powertrain, mixed, burst")
    tracegen.add_arguments(p)
    p.set_defaults(func=cmd_gen_trace)
