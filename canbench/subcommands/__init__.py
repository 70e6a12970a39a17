"""One module per canbench subcommand, each with add_subparser(sub) (cantools' pattern):
it adds its parser and sets func, which takes the parsed arguments and returns the exit code."""
from __future__ import annotations

from . import (
    compare,
    compose_override,
    ecu,
    gen_trace,
    identities,
    open_report,
    probe,
    run_scenario,
    scaffold,
    suite,
    summarise,
    validate,
    view,
)

# the order of `canbench --help`
ALL = (validate, compose_override, ecu, gen_trace, compare, summarise, scaffold, run_scenario, open_report, suite,
       view, identities, probe)
