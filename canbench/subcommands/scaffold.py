"""canbench scaffold TRACE --name N [--dbc F [--dbc-lenient]]: a scenario replaying a trace, gates derived from it;
with a DBC, cycle times from it (from_dbc) and proposed signal ranges, marked for review."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from .. import authoring, scenario
from ..errors import InputError, ScenarioError
from .summarise import bitrate


def cmd_scaffold(args) -> int:
    out = args.out or Path("scenarios") / f"{args.name}.yaml"
    if args.dbc_lenient and not args.dbc:
        raise InputError("--dbc-lenient", None, "reads the DBC --dbc names: give --dbc too")
    if not NAME.match(args.name):
        raise InputError("--name", None, f"{args.name!r}: a scenario's name is lowercase letters, digits, - and _ "
                         "(it names the test and the report)")
    if out.is_dir():
        raise InputError(str(out), None, "is a folder: --out names the scenario file (e.g. scenarios/my-drive.yaml)")
    if out.exists() and not args.force:
        raise InputError(str(out), None, "exists already (--force to overwrite)")
    for what, given in (("trace", args.trace), ("DBC", args.dbc)):
        if given is not None and out.exists() and given.exists() and out.samefile(given):
            raise InputError(str(out), None, f"is the {what} itself: --out names the scenario file to write")
    out.parent.mkdir(parents=True, exist_ok=True)
    text = authoring.scaffold(args.trace, args.name, out, args.bitrate, args.dbc, args.dbc_lenient)
    draft = out.with_name(f".{out.name}.draft")  # next to it: its paths are relative to the scenario
    draft.write_text(text)
    try:
        scenario.load(draft)  # what we write must be valid: an invalid scenario is not left behind
    except ScenarioError as e:
        draft.unlink()
        said = str(e).replace(str(draft), str(out))
        raise InputError(str(out), None, f"not written: the scaffold does not validate: {said}") from None
    draft.replace(out)
    for note in (line for line in text.splitlines() if line.startswith(NOTES)):
        print(note.removeprefix("# "))
    print(f"{out}: written; review its gates, then: make test SCENARIO={out}")
    return 0


NAME = re.compile(scenario.schema()["properties"]["name"]["pattern"])
# header lines said on the terminal too
NOTES = ("# The trace's interfaces", "# Not gated in cycle_time.ids", "# REVIEW: dbc_strict", "# Left out:")


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scaffold", help="write a scenario replaying a trace")
    p.add_argument("trace", type=Path)
    p.add_argument("--name", required=True, help="scenario name (lowercase, digits, - and _)")
    p.add_argument("--out", type=Path, help="default scenarios/<name>.yaml")
    p.add_argument("--bitrate", type=bitrate, default=500_000, help="for the bus load (default 500000)")
    p.add_argument("--dbc", type=Path, help="propose signal ranges and DBC cycle times from this DBC (review them)")
    p.add_argument("--dbc-lenient", action="store_true",
                   help="read a DBC strict reading refuses (signals that overlap or pass their message's end, "
                        "or that cantools reads wrong: docs/bench.md) "
                        "as written; the scenario then says dbc_strict: false")
    p.add_argument("--force", action="store_true")
    p.set_defaults(func=cmd_scaffold)
