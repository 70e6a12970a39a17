"""`canbench validate`: every problem of scenario files and of the traces they name, all at
once, one `file:line: field: message` line each, with paths as the user gave them.
scripts/bench-run runs it (in the orchestrator image) before anything starts."""
from __future__ import annotations

import sys
from pathlib import Path

from . import scenario
from .errors import InputError, ScenarioError, TraceError
from .trace import MAX_TRACE_FRAMES, STREAM_CACHE, iter_trace

MAX_PER_TRACE = 20  # a trace of FD frames would give one line per frame: the rest are counted


def trace_problems(path: Path) -> list[InputError]:
    """Every problem of a trace (iter_trace's checks, in every format): the scan goes on after each
    bad frame (read_trace stops at the first); one that stops its reader ends the list."""
    found: list[InputError] = []
    more = frames = 0

    def problem(error: TraceError) -> None:
        nonlocal more
        if len(found) < MAX_PER_TRACE:
            found.append(error)
        else:
            more += 1

    try:
        for _ in iter_trace(path, None, problem, STREAM_CACHE):
            frames += 1
    except TraceError as error:
        found.append(error)
    else:
        if not frames and not found:
            found.append(TraceError(str(path), None, "no frames in trace"))
        elif frames > MAX_TRACE_FRAMES:
            found.append(TraceError(str(path), None, f"more than {MAX_TRACE_FRAMES} frames: split the trace"))
    if more:
        found.append(TraceError(str(path), None, f"{more} more problems like the ones above"))
    return found


def named_traces(path: Path) -> list[Path]:
    """The traces a scenario names that exist, as the user wrote them (relative to the scenario),
    even when other parts of the scenario are wrong."""
    try:
        doc = scenario.parse(path)
    except ScenarioError:
        return []
    traces: list[Path] = []
    for key in ("ecus", "commands"):
        specs = doc.get(key)
        for spec in specs if isinstance(specs, list) else []:
            trace = spec.get("trace") if isinstance(spec, dict) else None
            if isinstance(trace, str) and (path.parent / trace).is_file() and path.parent / trace not in traces:
                traces.append(path.parent / trace)
    return traces


def problems(path: Path) -> list[InputError]:
    """Every problem of one scenario file and its traces, scenario first, each in line order."""
    found: list[InputError] = []
    try:
        scenario.load(path)
    except ScenarioError as e:
        found += getattr(e, "problems", [e])
    for trace in named_traces(path):
        found += trace_problems(trace)
    return found


def run(paths: list[Path]) -> int:
    """Exit code 2 if any file has a problem: all of them printed to stderr, one line each."""
    bad = 0
    count = 0
    for path in paths:
        found = problems(path)
        for problem in found:
            print(problem, file=sys.stderr)
        if found:
            bad += 1
            count += len(found)
        else:
            sc = scenario.load(path)
            print(f"{path}: ok ({len(sc.ecus)} ECUs on {', '.join(sc.bus_names)})")
    if count:
        print(f"canbench validate: {count} problem{'s' if count > 1 else ''} in {bad} of {len(paths)} "
              f"scenario file{'s' if len(paths) > 1 else ''}", file=sys.stderr)
        return 2
    return 0
