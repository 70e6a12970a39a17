"""canbench command line.

  canbench run SCENARIO                    run one scenario in compose (scripts/bench-run)
  canbench open [RUN]                      the HTML report of a run (default reports/latest)
  canbench view [--auto-subscribe ...]     bridges and ROS 2 topics on a Zenoh network, in Rerun
  canbench compare OLD NEW                 diff two runs' metrics.json; exit 1 on a regression
  canbench summarise TRACE                 per-id counts, cycle times, jitter and bus load of a trace
  canbench scaffold TRACE --name N         a scenario replaying a trace, gates derived from it
  canbench validate SCENARIO...            check scenario files and their traces
  canbench compose-override SCENARIO       compose override: bus, bridge settings, one service per ECU
  canbench ecu --scenario S --name N ...   run one emulated ECU (inside its container)
  canbench gen-trace --kind K --out F      write a synthetic trace (powertrain, mixed, burst)
  canbench suite plan|summary ...          make test's shards and its suite summary (scripts/bench-suite)

Errors are one line (file:line where it applies); --debug shows the traceback.
Exit codes: 0 ok, 1 run failure, 2 bad input."""
from __future__ import annotations

import argparse
import sys

from . import subcommands
from .errors import BenchError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="canbench", description=__doc__.split("\n")[0])
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="cmd", required=True)
    for command in subcommands.ALL:
        command.add_subparser(sub)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except BenchError as e:
        if args.debug:
            raise
        print(f"canbench: {e}", file=sys.stderr)
        return e.exit_code
    except (TimeoutError, OSError) as e:
        if args.debug:
            raise
        print(f"canbench: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
