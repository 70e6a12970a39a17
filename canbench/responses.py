"""Stimulus-response checks (expect.responses), on a run's captures decoded with the bus's DBC
(cantools):

  when  a command message (with these signals) is put on the tx key: its put time (commands.tsv)
        or a bus signal starts to meet a condition (false -> true, or true in the first frame):
        its bus time (can.log)
  then  within within_ms a frame of the response signal's message meets the condition: received
        on the bridge's rx key (side zenoh, the default: what a vehicle application sees) or
        on the bus (side can)

Each frame of the response message belongs to the latest stimulus before it. Per stimulus: the
first frame after it that meets the condition is its response (latency: its time minus the
stimulus's); none within within_ms is a late response (one came later, before the next
stimulus) or a missing one, named with the stimulus (commands.tsv:line or can.log:line) and what
was seen instead (the values in the window, or a matching frame that came before the stimulus:
an early one); with `once`, further matching frames before the next stimulus are duplicates.
metrics.json `responses.<name>`: stimuli, answered (in time), late, missing, duplicates, the
latency distribution of every response found (in time or late) and the problems."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .dbc import decode, grid_problem, judged_problem, message_of, name_problem, range_problem, raws_of, value_range
from .stats import latency_stats

if TYPE_CHECKING:
    from . import oracle

SHOW = 5
CONDITIONS = ("equals", "range", "one_of")


@dataclass(frozen=True)
class Condition:
    """A condition on one signal's physical value (value-table names already numbers: equals a name
    several values share is any of them). Values stay exact (a 64-bit integer is a Python int) and
    a float signal's are at its width, so the default tolerance (half a step; none for floats) is
    as strict as the signal."""
    equals: tuple[float, ...] | None = None
    tolerance: float = 0.0
    range: tuple[float, float] | None = None
    one_of: tuple[float, ...] | None = None
    text: str = ""

    def met(self, value: float) -> bool:
        if self.equals is not None and not any(abs(value - v) <= self.tolerance for v in self.equals):
            return False
        if self.range is not None and not self.range[0] <= value <= self.range[1]:
            return False
        if self.one_of is not None and not any(abs(value - v) <= self.tolerance for v in self.one_of):
            return False
        return True


def _numbers(signal, value) -> tuple[float, ...]:
    """The physical values a condition's value stands for, as frames carry them (dbc.raws_of)."""
    return tuple(signal.conversion.raw_to_scaled(raw, decode_choices=False) for raw in raws_of(signal, value))


def value_problem(signal, value) -> str | None:
    """Why a condition's value cannot be the signal's (None if it can): a name its value table
    lacks, a number YAML read as text, a number outside what the signal carries (never met)."""
    if isinstance(value, str):
        return name_problem(signal, value)
    if isinstance(value, int | float) and not isinstance(value, bool):
        return range_problem(signal, value) or grid_problem(signal, value)
    return None  # the schema's


def condition_problems(message, signal, spec: dict, where: list, fail) -> bool:
    """Each value of a `when`/`then` condition the signal cannot have, at its line; True if any."""
    if why := judged_problem(message, signal):
        fail([*where, "signal"], why)
        return True
    values: list[tuple[list, Any]] = [(["equals"], spec["equals"])] if "equals" in spec else []
    values += [(["one_of", k], v) for k, v in enumerate(spec.get("one_of") or [])]
    bad = False
    for key, value in values:
        problem = value_problem(signal, value)
        if problem:
            fail([*where, *key], problem)
            bad = True
    rng = spec.get("range")
    if isinstance(rng, list) and len(rng) == 2 and all(isinstance(x, int | float) for x in rng):
        lo, hi, source = value_range(signal)
        if rng[0] > rng[1]:
            fail([*where, "range"], f"min {rng[0]:g} is above max {rng[1]:g}")
            bad = True
        elif range_problem(signal, rng[0]) and range_problem(signal, rng[1]) and (rng[1] < lo or rng[0] > hi):
            unit = f" {signal.unit}" if signal.unit else ""
            fail([*where, "range"], f"[{rng[0]:g}, {rng[1]:g}] is outside {signal.name}'s range [{lo:g}, {hi:g}]"
                 f"{unit}" + (f" ({source})" if source else "") + ": no value meets it")
            bad = True
    return bad


def half_step(signal) -> float:
    """The default tolerance: half the signal's step, of either sign (a DBC's scale may be
    negative: -0.01 K), so the nearest value it carries meets it; none for a float signal."""
    return 0.0 if signal.is_float else abs(signal.scale) / 2


def condition(signal, spec: dict) -> Condition:
    """The condition of a `when`/`then` mapping (KeyError for a name not in the value table)."""
    tol = float(spec.get("tolerance", half_step(signal)))
    parts = []
    equals = rng = one_of = None
    if "equals" in spec:
        equals = _numbers(signal, spec["equals"])
        parts.append(f"== {spec['equals']}" + (f" +-{spec['tolerance']}" if "tolerance" in spec else ""))
    if "range" in spec:
        rng = (float(spec["range"][0]), float(spec["range"][1]))
        parts.append(f"in [{rng[0]:g}, {rng[1]:g}]")
    if "one_of" in spec:
        one_of = tuple(n for v in spec["one_of"] for n in _numbers(signal, v))
        parts.append(f"one of {list(spec['one_of'])}")
    return Condition(equals, tol, rng, one_of, " and ".join(parts) or "present")


@dataclass(frozen=True)
class Rule:
    name: str
    bus: str
    within_ms: float
    response_message: Any   # cantools Message
    response_signal: str
    then: Condition
    side: str = "zenoh"
    command: Any = None     # cantools Message of a command stimulus
    command_signals: tuple = ()  # ((signal, the values it stands for, tolerance), ...)
    stimulus_message: Any = None  # cantools Message of a bus-signal stimulus
    stimulus_signal: str = ""
    when: Condition | None = None
    count: int | None = None
    once: bool = False
    db: Any = None          # the bus's DBC: which frames are a message's (dbc.message_of)

    def stimulus_text(self) -> str:
        if self.command is not None:
            carried = ", ".join(f"{s} = {' or '.join(f'{v:g}' for v in vs)}" for s, vs, _ in self.command_signals)
            return f"{self.command.name}" + (f" {{{carried}}}" if carried else "") + " put"
        assert self.when is not None
        return f"{self.stimulus_message.name}.{self.stimulus_signal} {self.when.text} on the bus"

    def response_text(self) -> str:
        return f"{self.response_message.name}.{self.response_signal} {self.then.text}"


def _message_signal(db, key: str):
    message_name, _, signal_name = key.partition(".")
    message = db.get_message_by_name(message_name)  # KeyError: no such message
    return message, message.get_signal_by_name(signal_name)  # KeyError: no such signal


def rules(doc: dict, bus_dbcs: dict, load, fail) -> tuple[Rule, ...]:
    """expect.responses read against the buses' DBCs (load: path -> database); every unknown
    bus, message, signal or value-table name, and every value the signal cannot carry (a
    condition no frame meets), is a problem at its line (fail(where, message))."""
    specs = (doc.get("expect") or {}).get("responses") or []
    buses = [b["name"] for b in doc.get("buses", []) if isinstance(b, dict) and "name" in b]
    out = []
    for i, spec in enumerate(specs):
        where = ["expect", "responses", i]
        if not isinstance(spec, dict):
            continue
        bus = spec.get("bus", buses[0] if buses else "")
        if bus not in buses:
            fail([*where, "bus"], f"'{bus}' is not one of the buses {sorted(buses)}")
            continue
        if bus not in bus_dbcs:
            fail(where, f"needs a DBC for {bus}: give the scenario a dbc, or the bus one (buses[].dbc)")
            continue
        try:
            db = load(bus_dbcs[bus])
        except Exception:  # noqa: BLE001 - reported where the DBC is named
            continue
        when, then = spec.get("when") or {}, spec.get("then") or {}
        if ("command" in when) == ("signal" in when):
            fail([*where, "when"], "give either command (a command message) or signal (Message.Signal on the bus)")
            continue
        try:
            message, signal = _message_signal(db, then["signal"])
        except KeyError as e:
            fail([*where, "then", "signal"], f"{then['signal']}: not in the DBC ({e})")
            continue
        bad = condition_problems(message, signal, then, [*where, "then"], fail)  # the stimulus is checked too
        then_cond = None if bad else condition(signal, then)
        rule = dict(name=spec.get("name", f"response{i}"), bus=bus, within_ms=float(spec["within_ms"]), db=db,
                    response_message=message, response_signal=signal.name, then=then_cond,
                    side=then.get("side", "zenoh"), count=spec.get("count"), once=bool(spec.get("once", False)))
        if "command" in when:
            try:
                command = db.get_message_by_name(when["command"])
            except KeyError:
                fail([*where, "when", "command"], f"the DBC has no message {when['command']!r}")
                continue
            put = [c for c in doc.get("commands") or [] if isinstance(c, dict) and c.get("message") == command.name
                   and c.get("bus") == bus]
            if not put:
                fail([*where, "when", "command"], f"no command puts {command.name} on {bus} (commands[].message)")
            carried = []
            for name, value in (when.get("signals") or {}).items():
                try:
                    s = command.get_signal_by_name(name)
                except KeyError:
                    fail([*where, "when", "signals", name], f"{command.name} has no signal {name!r} "
                         f"(it has {sorted(x.name for x in command.signals)})")
                    bad = True
                    continue
                problem = value_problem(s, value)
                if problem:
                    fail([*where, "when", "signals", name], problem)
                    bad = True
                    continue
                carried.append((name, _numbers(s, value), half_step(s)))
            if not bad:
                out.append(Rule(**rule, command=command, command_signals=tuple(carried)))
        else:
            try:
                smessage, ssignal = _message_signal(db, when["signal"])
            except KeyError as e:
                fail([*where, "when", "signal"], f"{when['signal']}: not in the DBC ({e})")
                continue
            if not condition_problems(smessage, ssignal, when, [*where, "when"], fail) and not bad:
                out.append(Rule(**rule, stimulus_message=smessage, stimulus_signal=ssignal.name,
                                when=condition(ssignal, when)))
    return tuple(out)


def _values(db, message, signal: str, frames: list[oracle.Observed]) -> list[tuple[oracle.Observed, float]]:
    """(frame, the signal's physical value) of every frame of the message (undecodable ones left out)."""
    out = []
    for o in frames:
        f = o.frame
        if f.remote or message_of(db, f) is not message:
            continue
        try:
            value = decode(message, f.data).get(signal)
        except Exception:  # noqa: BLE001 - a frame the DBC cannot decode is no value
            continue
        if isinstance(value, int | float) and math.isfinite(value):
            out.append((o, value))  # exact: a 64-bit integer keeps its last bit
    return out


def stimuli(rule: Rule, commands: list[oracle.Observed], bus_frames: list[oracle.Observed]) -> list[oracle.Observed]:
    if rule.command is not None:
        out = []
        for o in commands:
            f = o.frame
            if f.can_id != rule.command.frame_id or f.extended != rule.command.is_extended_frame:
                continue
            try:
                decoded = decode(rule.command, f.data)
            except Exception:  # noqa: BLE001
                continue
            # a signal of a page this frame does not carry (its multiplexer selects another): not the command asked for
            if all(s in decoded and any(abs(decoded[s] - v) <= tol for v in vs) for s, vs, tol in rule.command_signals):
                out.append(o)
        return out
    assert rule.when is not None
    out, was = [], False
    for o, value in _values(rule.db, rule.stimulus_message, rule.stimulus_signal, bus_frames):
        now = rule.when.met(value)
        if now and not was:
            out.append(o)
        was = now
    return out


def _seen(items: list[tuple[oracle.Observed, float]], t0: int) -> str:
    listed = ", ".join(f"{v:g} at {(o.t_ns - t0) / 1e6:+.3f} ms ({_where(o)})" for o, v in items[:SHOW])
    return listed + (f", ... ({len(items) - SHOW} more)" if len(items) > SHOW else "")


def _where(o: oracle.Observed) -> str:
    return f"{o.origin}:{o.line}" if o.line else (f"zenoh #{o.index}" if o.key else f"{o.origin} #{o.index}")


def evaluate(rule: Rule, commands: list[oracle.Observed], bus_frames: list[oracle.Observed],
             zenoh_frames: list[oracle.Observed]) -> dict:
    """The rule on one run's frames: counts, latency distribution (ms) and problems."""
    window_ns = int(rule.within_ms * 1e6)
    starts = sorted(stimuli(rule, commands, bus_frames), key=lambda o: o.t_ns)
    seen = sorted(_values(rule.db, rule.response_message, rule.response_signal,
                          zenoh_frames if rule.side == "zenoh" else bus_frames), key=lambda ov: ov[0].t_ns)
    latencies: list[float] = []  # of every response found, in time or late
    answered = late = missing = duplicates = 0
    problems: list[str] = []
    j = 0  # the first response frame after the current stimulus
    for k, s in enumerate(starts):
        t0 = s.t_ns
        horizon = starts[k + 1].t_ns if k + 1 < len(starts) else math.inf
        while j < len(seen) and seen[j][0].t_ns <= t0:
            j += 1
        mine = []  # frames of the response message after this stimulus, before the next one
        while j < len(seen) and seen[j][0].t_ns <= horizon:
            mine.append(seen[j])
            j += 1
        meeting = [(o, v) for o, v in mine if rule.then.met(v)]
        what = f"{rule.name}: {rule.stimulus_text()} at {_where(s)}"
        if meeting:
            latencies.append((meeting[0][0].t_ns - t0) / 1e6)
        if meeting and meeting[0][0].t_ns - t0 <= window_ns:
            answered += 1
            if rule.once and len(meeting) > 1:
                duplicates += len(meeting) - 1
                problems.append(f"{what}: {len(meeting)} responses {rule.response_text()}, once expected: "
                                f"{_seen(meeting, t0)}")
        elif meeting:
            late += 1
            before = [m for m in mine if m[0].t_ns < meeting[0][0].t_ns]
            problems.append(f"{what}: {rule.response_text()} late, after {(meeting[0][0].t_ns - t0) / 1e6:.3f} ms "
                            f"(within {rule.within_ms:g} ms) ({_where(meeting[0][0])})"
                            + (f"; before it: {_seen(before, t0)}" if before else ""))
        else:
            missing += 1
            in_window = [m for m in mine if m[0].t_ns - t0 <= window_ns]
            early = [(o, v) for o, v in seen if t0 - window_ns <= o.t_ns <= t0 and rule.then.met(v)]
            instead = (f"seen instead: {_seen(in_window, t0)}" if in_window
                       else f"no {rule.response_message.name} frame within {rule.within_ms:g} ms"
                       + (f" (the next {_seen(mine[:1], t0)})" if mine else ""))
            if early:
                instead += f"; a matching one came before the stimulus: {_seen(early[-1:], t0)}"
            problems.append(f"{what}: no {rule.response_text()} within {rule.within_ms:g} ms; {instead}")
    if len(problems) > SHOW:  # one per stimulus: bounded as every check's list (metrics.json, junit.xml, report)
        problems[SHOW:] = [f"{rule.name}: ... ({len(problems) - SHOW} more stimuli with a problem; in all {late} "
                           f"late, {missing} missing, {duplicates} duplicated responses)"]
    if rule.count is not None and len(starts) != rule.count:
        listed = ", ".join(_where(s) for s in starts[:SHOW]) + (" ..." if len(starts) > SHOW else "")
        problems.insert(0, f"{rule.name}: {len(starts)} stimuli ({rule.stimulus_text()}), {rule.count} expected"
                        + (f": {listed}" if starts else ""))
    elif not starts:
        problems.insert(0, f"{rule.name}: no stimulus: nothing {rule.stimulus_text()}, so nothing judged")
    return {"bus": rule.bus, "side": rule.side, "within_ms": rule.within_ms, "stimuli": len(starts),
            "answered": answered, "late": late, "missing": missing, "duplicates": duplicates,
            "latency": latency_stats(latencies), "problems": problems}


def evaluate_all(rules_: tuple[Rule, ...], commands: list[tuple[str, oracle.Observed]], buses) -> dict:
    """metrics.json `responses`: per rule name, evaluate() on its bus (analysis.BusResult)."""
    by_bus = {b.bus: b for b in buses}
    out = {}
    for r in rules_:
        b = by_bus[r.bus]
        out[r.name] = evaluate(r, [c for bus, c in commands if bus == r.bus], b.bus_frames, b.zenoh_frames)
    return out
