"""Signal expectations (`expect.signals` of a scenario): per `Message.Signal` of a bus's DBC,
`range`, `equals`, `one_of` (numbers or the DBC's value-table names), `max_rate` (change per
second), `present` (seen at least N times), judged on the CAN side (the bus capture) and on the
Zenoh side (the frames of the bridge's samples), each decoded by cantools as the DBC says
(multiplexed signals only where their multiplexer selects them; signed, float and scaled values
as cantools returns them).

The evaluator is one streaming pass per side and bus: frames are fed in order and each gated
signal keeps running state only (count, min, max, the last value for the rate), at most
MAX_VIOLATIONS described violations (the rest counted), MARKS violations to mark, and a series
for the report thinned to at most PLOT_POINTS points (every other point dropped when full, so its
step doubles; 16 bytes a point), so an hour of traffic takes the memory of a minute of it: about
40 KiB per gated signal and side at most.

Validation (gates): a name the bus's DBC lacks, a value-table name the signal lacks, a number
YAML read as text ('12' quoted), or an expectation on a bus without a DBC is a scenario problem at
its file:line."""
from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from . import wire
from .dbc import decode, grid_problem, judged_problem, load_dbc, message_of, range_problem, raws_of, value_range
from .scenario import text_number

if TYPE_CHECKING:
    from .analysis import RunResult
    from .oracle import Observed

MAX_VIOLATIONS = 20  # described per signal and side; the rest are counted
PLOT_POINTS = 2000   # per signal and side, for report.html
MARKS = 200          # violations marked in the report per signal and side
SIDES = ("can", "zenoh")
OPERATORS = ("range", "equals", "one_of", "max_rate", "present")


@dataclass(frozen=True)
class Gate:
    """One `Message.Signal` expectation, its values already scaled as cantools decodes them."""
    key: str                      # Message.Signal
    message: str
    signal: str
    buses: tuple[str, ...]        # the buses it is judged on
    unit: str = ""
    range: tuple[float, float] | None = None
    equals: float | None = None               # as given (shown, plotted)
    one_of: tuple[float, ...] | None = None   # every value asked for, a name's values all
    max_rate: float | None = None  # unit per second
    present: int | None = None
    names: dict[float, str] = field(default_factory=dict)  # value-table names of the values above
    # equals and one_of as the raw values a frame carries (dbc.raws_of): judged exactly, so a 64-bit
    # integer or a 32-bit float is as strict as its bits, and a name stands for every value it names
    equals_raw: frozenset = frozenset()
    one_of_raw: frozenset = frozenset()

    def show(self, value: float, number: str | None = None) -> str:
        """A value as a user reads it: the number (as given, else 6 digits), its unit, and its
        value-table name."""
        text = f"{number or _num(value)}{' ' + self.unit if self.unit else ''}"
        name = self._name(value)
        return f"{text} ({name})" if name else text

    def _name(self, value: float) -> str | None:
        return next((n for v, n in self.names.items() if math.isclose(v, value, rel_tol=1e-9, abs_tol=1e-9)), None)

    def limits(self) -> str:
        parts = []
        if self.range:
            parts.append(f"[{_num(self.range[0])}, {_num(self.range[1])}]")
        if self.equals is not None:
            parts.append(f"= {self._name(self.equals) or _num(self.equals)}")
        if self.one_of is not None:
            parts.append("one of [" + ", ".join(dict.fromkeys(self._name(v) or _num(v) for v in self.one_of)) + "]")
        if self.max_rate is not None:
            parts.append(f"rate <= {_num(self.max_rate)}{' ' + self.unit if self.unit else ''}/s")
        if self.present is not None:
            parts.append(f"seen >= {self.present}")
        return ", ".join(parts)


def _num(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:.6g}"


def _apart(a: float, b: float) -> tuple[str, str]:
    """Two values shown with as many digits as it takes to tell them apart (a 32-bit float's 1.1
    and 1.1 asked for are 1.10000002 and 1.1)."""
    for digits in (6, 9, 12, 17):
        x = str(a) if isinstance(a, int) else f"{a:.{digits}g}"
        y = str(b) if isinstance(b, int) else f"{b:.{digits}g}"
        if x != y:
            return x, y
    return _num(a), _num(b)


# ---- validation: the scenario's expect.signals against the buses' DBCs ----

def gates(doc: Any, bus_dbcs: dict[str, Path], fail: Callable[[list, str], None]) -> tuple[Gate, ...]:
    """The scenario's signal gates; every problem passed to fail(where, message) (where: the
    path into the document, so the caller can name its line). DBCs that did not load are
    missing from bus_dbcs' loadable ones and reported by the caller."""
    specs = ((doc.get("expect") or {}).get("signals") or {}) if isinstance(doc.get("expect"), dict) else {}
    if not isinstance(specs, dict):
        return ()
    buses = [b["name"] for b in doc.get("buses", []) if isinstance(b, dict) and "name" in b]
    dbs = {}
    for bus in buses:
        if bus in bus_dbcs:
            try:
                dbs[bus] = load_dbc(bus_dbcs[bus])
            except Exception:  # noqa: BLE001 - the caller reports the DBC itself
                continue
    out = []
    for key, spec in specs.items():
        where = ["expect", "signals", key]
        if not isinstance(spec, dict) or not isinstance(key, str) or key.count(".") != 1:
            continue  # the schema refused it
        message_name, signal_name = key.split(".")
        if not set(spec) & set(OPERATORS) and set(spec) <= {*OPERATORS, "buses"}:  # (else the schema said)
            fail(where, f"nothing to judge: give at least one of {', '.join(OPERATORS)}")
            continue
        wanted = spec.get("buses")
        if isinstance(wanted, list):
            for i, bus in enumerate(wanted):
                if bus not in buses:
                    fail([*where, "buses", i], f"'{bus}' is not one of the buses {sorted(buses)}")
            candidates = [b for b in wanted if b in buses]
        else:
            candidates = buses
        with_dbc = [b for b in candidates if b in bus_dbcs]
        if not with_dbc:
            fail(where, "needs a DBC: give the scenario a dbc, or the bus (buses[].dbc)")
            continue
        on = [b for b in with_dbc if b in dbs and _message(dbs[b], message_name) is not None]
        if not on:
            if all(b in dbs for b in with_dbc):  # else the DBC did not load: reported by the caller
                names = sorted({m.name for b in with_dbc for m in dbs[b].messages})
                fail(where, f"no message {message_name} in the DBC of {', '.join(with_dbc)} "
                     f"({_listing(names)})")
            continue
        for b in _named_without(wanted, with_dbc, on):
            fail([*where, "buses"], f"the DBC of {b} has no message {message_name}")
        # the signal as each bus's DBC has it: judged where it is, missing where it was asked for
        found = {b: next((s for s in _message(dbs[b], message_name).signals if s.name == signal_name), None)
                 for b in on}
        having = [b for b in on if found[b] is not None]
        if not having:
            message = _message(dbs[on[0]], message_name)
            fail(where, f"message {message_name} has no signal {signal_name} "
                 f"({_listing([s.name for s in message.signals])})")
            continue
        for b in _named_without(wanted, on, having):
            fail([*where, "buses"], f"message {message_name} in the DBC of {b} has no signal {signal_name}")
        # a gate per definition of the signal: equals and one_of are judged on raw values, and two
        # buses' DBCs may scale a signal of one name differently (a gateway's 0.1 km/h for 0.01)
        alike: dict[tuple, list[str]] = {}
        for b in having:
            alike.setdefault(_definition(found[b]), []).append(b)
        for group in alike.values():
            signal = found[group[0]]
            said = (lambda at, text, g=group: fail(at, f"{text} (the DBC of {', '.join(g)})")) \
                if len(alike) > 1 else fail
            if why := judged_problem(_message(dbs[group[0]], message_name), signal):
                said(where, why)
                continue
            gate = _gate(key, message_name, signal, tuple(group), spec, where, said)
            if gate is not None:
                out.append(gate)
    return tuple(out)


def _definition(signal) -> tuple:
    """What makes a signal's raw values mean the same physical values and names."""
    return (signal.length, signal.byte_order, signal.is_signed, signal.is_float, signal.scale, signal.offset,
            signal.minimum, signal.maximum, tuple(sorted((raw, str(n)) for raw, n in (signal.choices or {}).items())))


def _named_without(wanted, candidates: list[str], having: list[str]) -> list[str]:
    """The candidate buses without what the others have, when the gate named its buses (buses: [...]):
    a named bus missing it is a problem; without buses, a gate judges wherever the DBC has it."""
    return [b for b in candidates if b not in having] if isinstance(wanted, list) else []


def _message(db, name: str):
    try:
        return db.get_message_by_name(name)
    except KeyError:
        return None


def _listing(names: list[str]) -> str:
    shown = ", ".join(names[:12])
    return f"it has {shown}" + (f", ... ({len(names) - 12} more)" if len(names) > 12 else "")


def _gate(key: str, message: str, signal, on: tuple[str, ...], spec: dict, where: list,
          fail: Callable[[list, str], None]) -> Gate | None:
    """The gate of one signal; a value-table name the signal lacks is a problem."""
    choices = {str(name): raw for raw, name in (signal.choices or {}).items()}
    names: dict[float, str] = {}
    ok = True

    def value(v, at: list) -> list[tuple[float, int | float]]:
        """(physical, raw) of each value v stands for (a name: every value it names)."""
        nonlocal ok
        if isinstance(v, bool) or not isinstance(v, int | float | str):
            return []  # the schema refused it
        if isinstance(v, str):
            if v not in choices:
                form = text_number(v)  # a value-table name first, even one that looks like a number
                listed = f" ({', '.join(choices)})" if choices else " (it has none)"
                fail(at, f"YAML reads {v!r} as text, not a number for {key}: write {form}" if form
                     else f"{v!r} is not in {key}'s value table{listed}")
                ok = False
                return []
            pairs = [(signal.conversion.raw_to_scaled(raw, decode_choices=False), raw) for raw in raws_of(signal, v)]
            for scaled, _ in pairs:
                names[float(scaled)] = v
            return pairs
        problem = range_problem(signal, v) or grid_problem(signal, v)  # no frame carries it: could only fail
        if problem:
            fail(at, problem)
            ok = False
            return []
        return [(v, raws_of(signal, v)[0])]

    rng = spec.get("range")
    equals, equals_raw = None, frozenset[int | float]()
    if "equals" in spec:
        pairs = value(spec["equals"], [*where, "equals"])
        equals, equals_raw = (pairs[0][0] if pairs else None), frozenset(raw for _, raw in pairs)
    one_of, one_of_raw = None, frozenset[int | float]()
    if isinstance(spec.get("one_of"), list):
        pairs = [p for i, v in enumerate(spec["one_of"]) for p in value(v, [*where, "one_of", i])]
        one_of, one_of_raw = tuple(scaled for scaled, _ in pairs), frozenset(raw for _, raw in pairs)
    if isinstance(rng, list) and len(rng) == 2 and all(isinstance(x, int | float) for x in rng) and rng[0] > rng[1]:
        fail([*where, "range"], f"min {rng[0]} is above max {rng[1]}")
        ok = False
    elif isinstance(rng, list) and len(rng) == 2 and all(isinstance(x, int | float) for x in rng):
        lo, hi, source = value_range(signal)
        if rng[1] < lo or rng[0] > hi:  # every value the signal carries is outside the gate
            unit = f" {signal.unit}" if signal.unit else ""
            fail([*where, "range"], f"[{rng[0]:g}, {rng[1]:g}] is outside {signal.name}'s range [{lo:g}, {hi:g}]"
                 f"{unit}" + (f" ({source})" if source else "") + ": every frame would fail it")
            ok = False
    for name, raw in choices.items():  # every value-table entry can be shown by name
        names.setdefault(float(signal.conversion.raw_to_scaled(raw, decode_choices=False)), name)
    if not ok:
        return None
    return Gate(key, message, signal.name, on, signal.unit or "",
                (float(rng[0]), float(rng[1])) if isinstance(rng, list) and len(rng) == 2 else None,
                equals, one_of, float(spec["max_rate"]) if "max_rate" in spec else None,
                int(spec["present"]) if "present" in spec else None, names, equals_raw, one_of_raw)


# ---- evaluation: one streaming pass per side and bus ----

@dataclass
class Series:
    """The running state of one gated signal on one side of one bus."""
    gate: Gate
    side: str
    bus: str
    count: int = 0
    min: float | None = None   # of the finite values
    max: float | None = None
    # per sender (frame id) the last (time its rate is judged at, value): a J1939 group's senders
    # each change at their own rate (dbc.message_of), one id per message otherwise
    last: dict[int, tuple[int, float]] = field(default_factory=dict)
    violations: list[str] = field(default_factory=list)
    more: int = 0  # violations beyond MAX_VIOLATIONS
    times: array = field(default_factory=lambda: array("d"))   # s since t0 of the plotted values, thinned
    values: array = field(default_factory=lambda: array("d"))  # (16 bytes a point: thousands of signals fit)
    step: int = 1   # every step-th value is kept for the plot
    marks: list[tuple[float, float]] = field(default_factory=list)  # violations, first MARKS

    @property
    def points(self) -> list[tuple[float, float]]:
        """(s since t0, value) of the plot series."""
        return list(zip(self.times, self.values, strict=True))

    @property
    def violation_count(self) -> int:
        return len(self.violations) + self.more

    def violate(self, text: str, t_s: float, value: float | None) -> None:
        if len(self.violations) < MAX_VIOLATIONS:
            self.violations.append(text)
        else:
            self.more += 1
        if value is not None and len(self.marks) < MARKS:
            self.marks.append((t_s, value))

    def add(self, t_ns: int, t0_ns: int, value: float, where: str | Callable[[], str],
            rate_t_ns: int | None = None, raw: int | float | None = None, exact: float | None = None,
            sender: int = 0) -> None:
        """One decoded value; where names its frame (a function giving that is called only for a
        violation, so good values build no strings); rate_t_ns: the time its rate is judged at
        (default t_ns; on Zenoh the bus stamp of the frame it was, as a batch arrives at once);
        raw: what the frame carries, for equals and one_of (default: value); exact: the physical
        value before it became a float (a 64-bit integer's every digit), for the messages; sender:
        the frame's id, whose previous value max_rate compares with."""
        g = self.gate
        raw = value if raw is None else raw
        exact = value if exact is None else exact
        rate_t = t_ns if rate_t_ns is None else rate_t_ns
        t_s = (t_ns - t0_ns) / 1e9

        def at() -> str:
            return f"at t={t_s:.3f} s, {where() if callable(where) else where}"
        if g.range and not g.range[0] <= value <= g.range[1]:
            self.violate(f"{g.key} = {g.show(value)} outside [{_num(g.range[0])}, {_num(g.range[1])}] {at()}",
                         t_s, value)
        if g.equals is not None and raw not in g.equals_raw:
            seen, asked = _apart(exact, g.equals)
            expected = (g.show(g.equals, asked) if len(g.equals_raw) <= 1
                        else f"{g._name(g.equals)} (each of the {len(g.equals_raw)} values it names)")
            self.violate(f"{g.key} = {g.show(value, seen)}, expected {expected} {at()}", t_s, value)
        if g.one_of is not None and raw not in g.one_of_raw:
            listed = list(dict.fromkeys(g._name(v) or _num(v) for v in g.one_of))
            self.violate(f"{g.key} = {g.show(value, _num(exact))} not one of [{', '.join(listed)}] {at()}", t_s, value)
        if g.max_rate is not None and (last := self.last.get(sender)) is not None:
            dt = (rate_t - last[0]) / 1e9
            change = abs(value - last[1])
            if change > 0 and (dt <= 0 or change / dt > g.max_rate):
                rate = "no time" if dt <= 0 else f"{dt * 1000:.3f} ms ({_num(change / dt)}/s > {_num(g.max_rate)}/s)"
                self.violate(f"{g.key} changed {g.show(last[1])} -> {g.show(value)} in {rate} {at()}",
                             t_s, value)
        self.count += 1
        if math.isfinite(value):  # a float signal's NaN would hide every extreme and is not JSON (metrics.json)
            self.min = value if self.min is None else min(self.min, value)
            self.max = value if self.max is None else max(self.max, value)
        self.last[sender] = (rate_t, value)
        if (self.count - 1) % self.step == 0:
            self.times.append(t_s)
            self.values.append(value)
            if len(self.times) >= PLOT_POINTS:
                self.times, self.values = self.times[::2], self.values[::2]
                self.step *= 2

    def finish(self, side_name: str) -> None:
        if self.gate.present is not None and self.count < self.gate.present:
            self.violate(f"{self.gate.key} seen {self.count} times {side_name}, expected at least "
                         f"{self.gate.present}", 0.0, None)

    def summary(self) -> dict:
        return {"count": self.count, "min": self.min, "max": self.max, "violations": self.violation_count,
                "limits": self.gate.limits(), "unit": self.gate.unit}


class Evaluator:
    """Feeds frames of one side of one bus through every gate of that bus (one pass)."""

    def __init__(self, gate_list: Iterable[Gate], db, side: str, bus: str, t0_ns: int):
        self.db, self.side, self.bus, self.t0_ns = db, side, bus, t0_ns
        self.series: dict[str, Series] = {}
        self.by_message: dict[str, list[Series]] = {}
        for g in gate_list:
            if bus in g.buses:
                s = Series(g, side, bus)
                self.series[g.key] = s
                self.by_message.setdefault(g.message, []).append(s)
        self._messages: dict[tuple[int, bool], Any] = {}
        self._conversions: dict[tuple[str, str], Any] = {}

    def _conversion(self, message, signal: str):
        k = (message.name, signal)
        if k not in self._conversions:
            self._conversions[k] = message.get_signal_by_name(signal).conversion
        return self._conversions[k]

    def _message(self, frame: wire.Frame):
        k = (frame.can_id, frame.extended)
        if k not in self._messages:
            m = message_of(self.db, frame)
            self._messages[k] = m if m is not None and m.name in self.by_message else None
        return self._messages[k]

    def feed(self, frame: wire.Frame, t_ns: int, where: str | Callable[[], str], rate_t_ns: int | None = None) -> None:
        """One frame; where names it (file:line or the sample), or is a function giving that,
        called only when something is wrong, so good frames build no strings; rate_t_ns: see
        Series.add."""
        if frame.remote:
            return
        message = self._message(frame)
        if message is None:
            return
        series = self.by_message[message.name]
        try:  # raw values: equals and one_of are judged on what the frame carries
            decoded = decode(message, frame.data, scaling=False)
        except Exception as e:  # noqa: BLE001 - cantools' errors name what does not fit
            t_s = (t_ns - self.t0_ns) / 1e9
            for s in series:
                s.violate(f"{s.gate.key}: {message.name} frame {wire.id_hex(frame.can_id, frame.extended)}#"
                          f"{frame.data.hex().upper()} does not decode ({e}) at t={t_s:.3f} s, "
                          f"{where() if callable(where) else where}", t_s, None)
            return
        for s in series:
            raw = decoded.get(s.gate.signal)
            if isinstance(raw, int | float):  # else a multiplexed signal not selected in this frame
                exact = self._conversion(message, s.gate.signal).raw_to_scaled(raw, decode_choices=False)
                s.add(t_ns, self.t0_ns, float(exact), where, rate_t_ns, raw, exact, frame.can_id)

    def finish(self) -> list[Series]:
        side_name = "on the bus" if self.side == "can" else "on Zenoh"
        for s in self.series.values():
            s.finish(f"{side_name} {self.bus}")
        return list(self.series.values())


@dataclass
class SignalRun:
    """Every gated signal's series, per side and bus."""
    series: list[Series]
    t0_ns: int

    def of(self, side: str) -> list[Series]:
        return [s for s in self.series if s.side == side]

    def problems(self, side: str) -> list[str]:
        out = self._judged_nothing(side)
        for s in self.of(side):
            if s.violation_count:
                shown = "; ".join(s.violations)
                out.append(f"{s.bus} {s.gate.key}: {s.violation_count} violation"
                           f"{'s' if s.violation_count > 1 else ''}: {shown}"
                           + (f"; ... ({s.more} more)" if s.more else ""))
        return out

    def _judged_nothing(self, side: str) -> list[str]:
        """A gate with no value on any of its buses judged nothing, and passing it would say the
        signal was right: a problem on the bus (the message never sent, its multiplexer page never
        selected, an address the DBC's id does not have); on Zenoh only where the bus had values."""
        counts: dict[str, dict[str, int]] = {}
        for s in self.series:
            counts.setdefault(s.gate.key, {}).setdefault(s.side, 0)
            counts[s.gate.key][s.side] += s.count + s.violation_count  # an undecodable frame was judged
        out = []
        for s in self.of(side):
            key = s.gate.key
            if key in counts and counts[key].get(side) == 0 and (side == "can" or counts[key].get("can", 0) > 0):
                buses = sorted({x.bus for x in self.of(side) if x.gate.key == key})
                where = "on the bus" if side == "can" else "on Zenoh"
                out.append(f"{', '.join(buses)} {key}: no value {where}, so the gate judged nothing "
                           f"({s.gate.message} never {'sent' if side == 'can' else 'arrived'}, or never with "
                           "this signal's multiplexer page)")
                del counts[key]
        return out

    def summary(self) -> dict:
        """metrics.json `signals`: side -> bus -> Message.Signal -> count, min, max, violations."""
        out: dict[str, dict] = {}
        for s in self.series:
            out.setdefault(s.side, {}).setdefault(s.bus, {})[s.gate.key] = s.summary()
        return out


def _zenoh_sources(b) -> dict[int, Observed]:
    """Zenoh frame index -> the bus frame the oracle paired it with (matched or corrupted)."""
    sent: dict[int, Observed] = {}
    for s, r in b.comparison.matched:
        sent[r.index] = s
    for s, r, _ in b.comparison.corrupted:
        sent[r.index] = s
    return sent


def _zenoh_place(o: Observed, source: Observed | None) -> Callable[[], str]:
    """A Zenoh frame named by its sample and the bus frame it was."""
    return lambda: (f"zenoh #{o.index} seq {o.seq}"
                    + (f" (sent as {source.origin}:{source.line})" if source is not None and source.line else ""))


def evaluate(result: RunResult) -> SignalRun:
    """The scenario's signal gates over the run's captures, once per result (kept on it)."""
    cached = getattr(result, "_signal_run", None)
    if cached is not None:
        return cached
    sc = result.scenario
    gate_list = getattr(sc, "signal_gates", ())
    starts = [o.t_ns for b in result.buses for o in (b.bus_frames or b.can_frames)[:1]]
    t0 = min(starts) if starts else 0
    series: list[Series] = []
    for b in result.buses:
        path = sc.bus_dbcs.get(b.bus) if gate_list else None
        if path is None or not any(b.bus in g.buses for g in gate_list):
            continue
        db = load_dbc(path)
        can = Evaluator(gate_list, db, "can", b.bus, t0)
        for o in b.bus_frames or b.can_frames:
            can.feed(o.frame, o.t_ns, f"{o.origin}:{o.line}" if o.line else f"{o.origin} #{o.index}")
        series += can.finish()
        zen = Evaluator(gate_list, db, "zenoh", b.bus, t0)
        sources = _zenoh_sources(b)
        for o in b.zenoh_frames:  # a rate at the bus stamp: the frames of one batch arrive at one time
            source = sources.get(o.index)
            zen.feed(o.frame, o.t_ns, _zenoh_place(o, source), source.t_ns if source is not None else None)
        series += zen.finish()
    run = SignalRun(series, t0)
    try:
        object.__setattr__(result, "_signal_run", run)
    except AttributeError:
        pass
    return run
