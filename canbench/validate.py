"""`canbench validate`: every problem of scenario files and of the traces they name, all at
once, one `file:line: field: message` line each, with paths as the user gave them.
scripts/bench-run runs it (in the orchestrator image) before anything starts."""
from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path

from . import scenario
from .dbc import load_dbc, strict_problem
from .errors import InputError, ScenarioError, TraceError
from .files import is_file
from .trace import MAX_TRACE_FRAMES, STREAM_CACHE, interfaces_said, iter_trace, several_interfaces, too_many_frames
from .wire import EXT_ID_MAX, STD_ID_MAX

MAX_PER_TRACE = 20  # a trace of FD frames would give one line per frame: the rest are counted


def trace_problems(path: Path, interfaces: dict[str | None, int] | None = None) -> list[InputError]:
    """Every problem of a trace (iter_trace's checks, in every format): the scan goes on after each
    bad frame (read_trace stops at the first); one that stops its reader ends the list.
    interfaces: filled with the trace's interfaces, each with its count of frames (a trace of
    several is too long only on the one a scenario replays: interface_problems)."""
    found: list[InputError] = []
    more = frames = 0
    seen = {} if interfaces is None else interfaces

    def problem(error: TraceError) -> None:
        nonlocal more
        if len(found) < MAX_PER_TRACE:
            found.append(error)
        else:
            more += 1

    try:
        for _, _, iface, _ in iter_trace(path, None, problem, STREAM_CACHE):
            frames += 1
            seen[iface] = seen.get(iface, 0) + 1
    except TraceError as error:
        found.append(error)
    else:
        if not frames and not found:
            found.append(TraceError(str(path), None, "no frames in trace"))
        elif len(seen) == 1 and frames > MAX_TRACE_FRAMES:
            found.append(TraceError(str(path), None, too_many_frames()))
    if more:
        found.append(TraceError(str(path), None, f"{more} more problems like the ones above"))
    return found


def named_traces(path: Path, doc) -> list[Path]:
    """The traces a scenario (path, its parsed document) names that exist, as the user wrote them
    (relative to the scenario), even when other parts of the scenario are wrong."""
    traces: list[Path] = []
    for _, _, _, trace in trace_specs(doc):
        if is_file(path.parent / trace) and path.parent / trace not in traces:
            traces.append(path.parent / trace)
    return traces


def trace_specs(doc) -> Iterator[tuple[str, int, dict, str]]:
    """(ecus or commands, index, entry, its trace as written) of every entry of a parsed scenario that
    names a trace, whatever else in it is wrong."""
    for key in ("ecus", "commands"):
        specs = doc.get(key)
        for i, spec in enumerate(specs if isinstance(specs, list) else []):
            if isinstance(spec, dict) and isinstance(spec.get("trace"), str):
                yield key, i, spec, spec["trace"]


def interface_problems(path: Path, doc, interfaces_of: dict[Path, dict[str | None, int]]) -> list[InputError]:
    """A trace of several interfaces replayed without `interface` (a bus carries one: merged, two
    buses' frames would go on one, out of time order), or an `interface` the trace does not have."""
    found: list[InputError] = []
    for key, i, spec, trace in trace_specs(doc):
        if key == "ecus" and spec.get("role", "replay") != "replay":
            continue  # only a replay sends its trace
        seen = interfaces_of.get(path.parent / trace)
        if not seen:
            continue  # no such trace, or no frames: said already
        only = scenario.interface_name(spec.get("interface"))
        if only is not None and only not in seen:
            found.append(ScenarioError(str(path), scenario.line_of(doc, [key, i, "interface"]),
                                       f"{key}.{i}.interface: no frames on '{only}' in {trace} "
                                       f"({interfaces_said(seen)})"))
        elif only is None and len(seen) > 1:
            found.append(ScenarioError(str(path), scenario.line_of(doc, [key, i, "trace"]),
                                       f"{key}.{i}.trace: {trace} has {several_interfaces(seen)}"))
        elif only is not None and len(seen) > 1 and seen[only] > MAX_TRACE_FRAMES:
            found.append(ScenarioError(str(path), scenario.line_of(doc, [key, i, "interface"]),
                                       f"{key}.{i}.interface: {trace} on '{only}': {too_many_frames()}"))
    return found


def remap_problems(path: Path, doc) -> list[InputError]:
    """An id_remap that gives an 11-bit frame of its trace an id above 7FF (the frame keeps its
    format): one problem per remapped id, at the remap's line, naming the trace line."""
    found: list[InputError] = []
    for key, i, spec, trace in trace_specs(doc):
        remap = spec.get("id_remap")
        if key != "ecus" or not isinstance(remap, dict) or not is_file(path.parent / trace):
            continue
        try:
            wide = {int(k, 16): (k, v) for k, v in remap.items() if STD_ID_MAX < int(v, 16) <= EXT_ID_MAX}
        except (TypeError, ValueError):
            continue  # the schema's problem
        seen: set[int] = set()
        try:
            only = scenario.interface_name(spec.get("interface"))
            for line, _, iface, frame in iter_trace(path.parent / trace, None, lambda e: None, STREAM_CACHE):
                if only is not None and iface != only:
                    continue  # another bus's frame: not replayed
                if not frame.extended and frame.can_id in wide and frame.can_id not in seen:
                    seen.add(frame.can_id)
                    key, target = wide[frame.can_id]
                    found.append(ScenarioError(str(path), scenario.line_of(doc, ["ecus", i, "id_remap", key]),
                                               f"ecus.{i}.id_remap.{key}: the 11-bit frames of {key} ({trace}:{line}) "
                                               f"would get id {target}, above 7FF"))
        except TraceError:
            continue  # trace_problems says it
    return found


def encoding_problems(path: Path, doc, sc: scenario.Scenario) -> list[InputError]:
    """What the DBC encodes (restbus ECUs, commands in signals) made as the run makes it: a frame
    cantools cannot encode (whatever the value checks of scenario.load let through) is a problem
    at the entry's line here, not a traceback once the run started."""
    from . import plans
    found: list[InputError] = []
    def check(where: list, make: Callable[[], object]) -> None:
        try:
            make()
        except Exception as e:  # noqa: BLE001 - cantools' encode errors say what it could not encode
            found.append(ScenarioError(str(path), scenario.line_of(doc, where),
                                       f"{'.'.join(map(str, where))}: a frame cannot be encoded with the DBC: {e}"))

    from . import restbus
    for i, ecu in enumerate(sc.ecus):
        if ecu.role == "restbus":
            for plan in ecu.restbus:  # every page once, at the start
                check(["ecus", i], partial(restbus.every_page, plan))
            check(["ecus", i], partial(plans.schedule, ecu, sc))  # makes each message's last frame
    for i, command in enumerate(sc.commands):
        if command.signal_plan is not None:
            check(["commands", i], partial(_first_frame, command))
    return found


def traffic_end(sc: scenario.Scenario) -> tuple[float, str] | None:
    """When the scenario's last planned frame goes out (s from the start, speed, loops and offsets
    applied: the plans the ECUs and the consumer send by), and whose it is."""
    from . import commands, plans
    ends = [(plan.last.timestamp, f"ECU {e.name}'s last frame") for e in sc.ecus
            if e.role not in ("echo", "responder")  # these answer, on no schedule of their own (canbench.ecu.run)
            and (plan := plans.schedule(e, sc)).last is not None]
    ends += [(t, f"the last command (bus {bus})") for t, bus, _, _ in commands.plan(sc)[-1:]]
    return max(ends, default=None)


def duration_problems(path: Path, doc, sc: scenario.Scenario) -> list[InputError]:
    """Traffic planned past duration_s, the upper bound of the traffic phase: found here, at its
    line, not as a bench error after the whole stack started and waited duration_s + 30 s."""
    end = traffic_end(sc)
    if end is None or end[0] <= sc.duration_s:
        return []
    return [ScenarioError(str(path), scenario.line_of(doc, ["duration_s"]),
                          f"duration_s: {sc.duration_s:g} s ends before the traffic does: {end[1]} goes out at "
                          f"{end[0]:.3f} s (speed, loops and start offsets applied); give duration_s at least that")]


def _first_frame(command: scenario.Commands) -> object:
    from . import restbus
    return next(iter(restbus.command_frames(command)), None)


def problems(path: Path) -> list[InputError]:
    """Every problem of one scenario file and its traces, scenario first, each in line order."""
    return checked(path)[0]


def checked(path: Path) -> tuple[list[InputError], scenario.Scenario | None]:
    """(every problem of one scenario file and its traces, the scenario when it loads), the file
    read and parsed once."""
    try:
        doc = scenario.parse(path)
    except ScenarioError as e:
        return [e], None
    found: list[InputError] = []
    sc = None
    try:
        sc = scenario.build(path, doc)
        found += encoding_problems(path, doc, sc)
    except ScenarioError as e:
        found += getattr(e, "problems", [e])
    found += remap_problems(path, doc)
    interfaces_of: dict[Path, dict[str | None, int]] = {}
    traces_found: list[InputError] = []
    for trace in named_traces(path, doc):
        traces_found += trace_problems(trace, interfaces_of.setdefault(trace, {}))
    found += interface_problems(path, doc, interfaces_of) + traces_found
    if sc is not None and not found:  # the plans read the traces: only once they are known good
        found += duration_problems(path, doc, sc)
    return found, sc


def run(paths: list[Path]) -> int:
    """Exit code 2 if any file has a problem: all of them printed to stderr, one line each."""
    bad = 0
    count = 0
    for path in paths:
        found, sc = checked(path)
        for problem in found:
            print(problem, file=sys.stderr)
        if found or sc is None:
            bad += 1
            count += len(found)
        else:
            print(f"{path}: ok ({len(sc.ecus)} ECUs on {', '.join(sc.bus_names)})")
            for ecu in sc.ecus:
                if ecu.left_out:
                    print(f"{path}: note: ECU {ecu.name} ({ecu.dbc_node}) leaves out {', '.join(ecu.left_out)}")
            for dbc_path in sorted(set(sc.bus_dbcs.values())):
                if why := strict_problem(load_dbc(dbc_path)):  # dbc_strict: false let it in
                    print(f"{path}: note: {dbc_path.name} is read as written (dbc_strict: false): {why}; each such "
                          "message signal by signal, and the bench sends none of them")
    if count:
        print(f"canbench validate: {count} problem{'s' if count > 1 else ''} in {bad} of {len(paths)} "
              f"scenario file{'s' if len(paths) > 1 else ''}", file=sys.stderr)
        return 2
    return 0
