"""Frames from signals, with a DBC (cantools encodes every frame): the restbus ECU role (every
message a DBC node transmits, at its GenMsgCycleTime), commands in signals, and the responder
role's answers.

A signal's value comes from the scenario (a constant: a number or a value-table name; a ramp
`{ramp: [from, to], over_s: T}`; a signal trace in CSV, `time_s,value` per line, held until the
next line) or else from the DBC: GenSigStartValue, and the value of raw 0 where it has none.
A multiplexer the scenario does not set selects its message's pages in turn, one per frame
(ascending ids, nested multiplexers within the pages that carry them), as an ECU sending every
page does; its GenSigStartValue or raw 0 need not be one of its ids. Signals the scenario names
as counters count 0, 1, ... per frame that carries them (each frame of their message; of their
pages for a signal of some pages only) and wrap after their largest value (within the DBC range
where the signal has one: [1|15] counts 1 to 15); a checksum signal (one
whole byte, raw = physical) carries, in the frames that carry it, over the other bytes of the
payload in order:

  xor             every byte XORed together
  crc8_sae_j1850  CRC-8 SAE J1850: polynomial 0x1D, initial 0xFF, final XOR 0xFF, not reflected
                  (crccheck's Crc8SaeJ1850; "123456789" -> 0x4B)

The bench carries CAN 2.0 frames: a restbus node's CAN FD messages of more than 8 data bytes are
left out and said (Ecu.left_out: `canbench validate` and the ECU's log name them), those of up to
8 go as CAN 2.0 frames; a command, a request or an answer of more than 8 bytes is a problem.

Plans are made lazily, like the replay ECU's (canbench.plans): an hour of a restbus node is
hundreds of thousands of frames, each encoded as it is sent."""
from __future__ import annotations

import csv
import heapq
import math
from array import array
from bisect import bisect_right
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import can
from crccheck.crc import Crc8SaeJ1850

from .dbc import (
    bits_range,
    cycle_time_ms,
    decode,
    encode_problem,
    group_read,
    name_problem,
    range_problem,
    saved_text,
    send_type_cyclic,
    too_long_for_can_20,
)
from .scenario import YAML_BOOLS, text_number


def xor8(data: bytes) -> int:
    out = 0
    for b in data:
        out ^= b
    return out


def crc8_sae_j1850(data: bytes) -> int:
    return Crc8SaeJ1850.calc(data)


CHECKSUMS: dict[str, Callable[[bytes], int]] = {"xor": xor8, "crc8_sae_j1850": crc8_sae_j1850}


# --- where a signal's value comes from ------------------------------------------------------

@dataclass(frozen=True)
class Constant:
    value: float | str  # a number, or a name of the signal's value table

    def at(self, t: float) -> float | str:
        return self.value


@dataclass(frozen=True)
class Ramp:
    start: float
    end: float
    over_s: float

    def at(self, t: float) -> float:
        return self.start + (self.end - self.start) * min(max(t, 0.0) / self.over_s, 1.0)


@dataclass(frozen=True)
class SignalTrace:
    """A CSV signal trace: the value of the last line at or before t (the first line's before it)."""
    path: Path
    times: array
    values: tuple

    def at(self, t: float) -> float | str:
        return self.values[max(bisect_right(self.times, t) - 1, 0)]


Source = Constant | Ramp | SignalTrace


@dataclass(frozen=True)
class MessagePlan:
    """One DBC message's frames: values per signal, a rolling counter, a checksum, a cycle."""
    message: Any  # cantools.database.can.Message
    sources: dict[str, Source] = field(default_factory=dict)
    counter: str | None = None
    checksum: tuple[str, str] | None = None  # (signal, algorithm)
    cycle_ms: float | None = None

    def values(self, t: float) -> dict:
        """Every signal's value at t; a multiplexer the scenario does not set is left out (encode
        gives it the frame's page) unless it selects no pages (then it is a plain signal)."""
        paged = self.message.is_multiplexed()
        return {s.name: self.sources[s.name].at(t) if s.name in self.sources else default_value(s)
                for s in self.message.signals if s.name in self.sources or not (s.is_multiplexer and paged)}

    def encode(self, values: dict, n: int) -> bytes:
        """The payload of the n-th frame with these signal values (counter and checksum applied
        where the frame's page carries them; multiplexers not in values at the n-th of the pages
        the given ones allow)."""
        m = self.message
        allowed: list[dict[str, int]] = [{}]
        if m.is_multiplexed():
            allowed = _pages(m, tuple((k, v) for k, v in values.items() if k in multiplexers(m)))
            values.update(allowed[n % len(allowed)])
        page = allowed[n % len(allowed)]
        if self.counter:
            counts = counter_values(m.get_signal_by_name(self.counter))
            values[self.counter] = counts[carried_count(m, self.counter, allowed, n) % len(counts)]
        checksum = self.checksum if self.checksum and on_page(m, self.checksum[0], page) else None
        if checksum:
            values[checksum[0]] = 0
        data = bytearray(m.encode(values, scaling=True, strict=False))
        if checksum:
            at = checksum_byte(m, checksum[0])
            data[at] = CHECKSUMS[checksum[1]](bytes(data[:at] + data[at + 1:]))
        return bytes(data)

    def frame(self, n: int, t: float, start: float, bus: str) -> can.Message:
        m = self.message
        return can.Message(timestamp=start + t, arbitration_id=m.frame_id, is_extended_id=m.is_extended_frame,
                           dlc=m.length, data=self.encode(self.values(t), n), channel=bus)


def every_page(plan: MessagePlan, t: float = 0.0) -> None:
    """Encodes one frame of each page the plan sends at t (a check before a run: the run encodes
    them as it goes); an error names the message."""
    allowed = _pages(plan.message, ()) if plan.message.is_multiplexed() else [{}]
    for n in range(min(len(allowed), MAX_PAGES_CHECKED)):
        try:
            plan.encode(plan.values(t), n)
        except Exception as e:  # noqa: BLE001 - cantools' encode errors say what it could not encode
            raise ValueError(f"{plan.message.name}: {e}") from None


MAX_PAGES_CHECKED = 256


def default_value(signal) -> float | str:
    """GenSigStartValue (a raw value, scaled), else the value of raw 0: a number, not cantools'
    `initial`, which is a value-table entry where the table names it (a multiplexer without pages
    takes int() of it)."""
    raw = signal.raw_initial if signal.raw_initial is not None else 0
    return signal.conversion.raw_to_scaled(raw, decode_choices=False)


@lru_cache(maxsize=256)
def multiplexers(message) -> frozenset[str]:
    return frozenset(s.name for s in message.signals if s.is_multiplexer)


@lru_cache(maxsize=256)  # per frame of an hour's plan: the same few selections
def _pages(message, given: tuple) -> list[dict[str, int]]:
    return pages(message, dict(given))


def multiplexer_ids(message, name: str) -> list[int]:
    """The ids a multiplexer selects pages by (its signals' m<id>s in the DBC), ascending."""
    return sorted({i for s in message.signals if s.multiplexer_signal == name for i in s.multiplexer_ids or ()})


def pages(message, given: dict) -> list[dict[str, int]]:
    """Every page of a multiplexed message (multiplexer -> id, nested multiplexers within the page
    that carries them), in ascending ids; a multiplexer in given (its value or value-table name)
    keeps that value."""
    def number(name: str, value) -> int:
        if isinstance(value, str):
            return int(message.get_signal_by_name(name).conversion.choice_to_number(value))
        return int(value)  # as cantools takes a multiplexer's value

    def level(names: list[str]) -> list[dict[str, int]]:
        out: list[dict[str, int]] = [{}]
        for name in names:
            ids = [number(name, given[name])] if name in given else \
                multiplexer_ids(message, name) or [int(default_value(message.get_signal_by_name(name)))]  # no pages
            options = [{name: i, **inner} for i in ids
                       for inner in level([s.name for s in message.signals if s.is_multiplexer
                                           and s.multiplexer_signal == name and i in (s.multiplexer_ids or ())])]
            out = [{**a, **b} for a in out for b in options]
        return out
    return level([s.name for s in message.signals if s.is_multiplexer and s.multiplexer_signal is None])


def on_page(message, name: str, page: dict[str, int]) -> bool:
    """Whether a page (multiplexer -> id; {} for a message without) carries the signal: every
    multiplexer above it selects it."""
    signal = message.get_signal_by_name(name)
    while signal.multiplexer_signal is not None:
        if page.get(signal.multiplexer_signal) not in (signal.multiplexer_ids or ()):
            return False
        signal = message.get_signal_by_name(signal.multiplexer_signal)
    return True


def carried_count(message, name: str, allowed: list[dict[str, int]], n: int) -> int:
    """How many frames before the n-th carried the signal, the pages going in turn (n for a
    signal of every page)."""
    carrying = [i for i, page in enumerate(allowed) if on_page(message, name, page)]
    turn = n % len(allowed)
    return (n // len(allowed)) * len(carrying) + sum(1 for i in carrying if i < turn)


def mux_ids(message, name: str) -> list[int] | None:
    """A multiplexer's ids, None for any other signal."""
    return multiplexer_ids(message, name) if name in multiplexers(message) else None


def counter_values(signal) -> range:
    """What a counter signal counts through: its DBC range where it has one ([1|15] counts 1 to
    15 and wraps to 1, as AUTOSAR E2E counters that keep 0 for "not valid" do), else all its
    bits can hold. Empty where the range holds no value its bits can carry."""
    low, top = 0, 2 ** signal.length - 1
    if signal.minimum is not None:
        low = max(low, math.ceil(signal.minimum))
    if signal.maximum is not None:
        top = min(top, math.floor(signal.maximum))
    return range(low, top + 1)


def checksum_byte(message, name: str) -> int:
    """The payload byte a one-byte signal occupies (ValueError if it is not exactly one byte)."""
    if message.get_signal_by_name(name).length != 8:
        raise ValueError("a checksum signal fills exactly one byte of the payload (8 bits, byte-aligned)")
    every = pages(message, {}) if message.is_multiplexed() else [{}]
    page = next((p for p in every if on_page(message, name, p)), {})  # one that carries it
    values = {s.name: 0 for s in message.signals} | page
    zero = message.encode({**values, name: 0}, scaling=False, strict=False)
    full = message.encode({**values, name: 0xFF}, scaling=False, strict=False)  # the byte(s) it takes
    ones = [i for i, (a, b) in enumerate(zip(zero, full, strict=True)) if a != b]
    if len(ones) != 1 or zero[ones[0]] ^ full[ones[0]] != 0xFF:
        raise ValueError("a checksum signal fills exactly one byte of the payload (8 bits, byte-aligned)")
    return ones[0]


# --- plans ----------------------------------------------------------------------------------

def frame_count(plan: MessagePlan, run_s: float) -> int:
    assert plan.cycle_ms
    return max(1, int(run_s * 1000 / plan.cycle_ms))


def _one(plan: MessagePlan, run_s: float, start: float, bus: str) -> Iterator[can.Message]:
    assert plan.cycle_ms
    return (plan.frame(n, n * plan.cycle_ms / 1000, start, bus) for n in range(frame_count(plan, run_s)))


def frames(plans: tuple[MessagePlan, ...], run_s: float, start: float, bus: str) -> Iterator[can.Message]:
    """Every message's frames for run_s in time order (then id), made as they are consumed."""
    return heapq.merge(*(_one(p, run_s, start, bus) for p in plans),
                       key=lambda f: (f.timestamp, f.arbitration_id))


def last_frame(plans: tuple[MessagePlan, ...], run_s: float, start: float, bus: str) -> can.Message | None:
    lasts = [(p.frame(frame_count(p, run_s) - 1, (frame_count(p, run_s) - 1) * (p.cycle_ms or 0) / 1000, start,
                      bus), i) for i, p in enumerate(plans)]
    return max(lasts, key=lambda fi: (fi[0].timestamp, fi[0].arbitration_id, fi[1]))[0] if lasts else None


def restbus_plan(ecu):
    """The restbus ECU's plan (canbench.plans.Plan): its messages at their cycles for run_s."""
    from .plans import Plan  # plans imports this module
    plans, run_s, start, bus = ecu.restbus, ecu.run_s, ecu.start_offset_s, ecu.bus
    last = last_frame(plans, run_s, start, bus)
    return Plan(frames=lambda: ((0, m) for m in frames(plans, run_s, start, bus)),
                count=sum(frame_count(p, run_s) for p in plans), last=last,
                last_id_count=sum(frame_count(p, run_s) for p in plans if last is not None and
                                  (p.message.frame_id, p.message.is_extended_frame)
                                  == (last.arbitration_id, last.is_extended_id)))


def command_frames(c) -> Iterator[tuple[int, can.Message]]:
    """A command in signals (canbench.scenario.Commands with signal_plan): every cycle for run_s,
    or one frame per schedule entry (each entry's signals stay until an entry changes them)."""
    p: MessagePlan = c.signal_plan
    if not c.schedule:
        return ((0, m) for m in _one(p, c.run_s, c.start_offset_s, c.bus))

    def scheduled() -> Iterator[tuple[int, can.Message]]:
        held: dict = {}
        m = p.message
        for n, (at_s, values, line) in enumerate(c.schedule):
            held.update(values)
            merged = {**p.values(at_s), **held}
            yield line, can.Message(timestamp=c.start_offset_s + at_s, arbitration_id=m.frame_id,
                                    is_extended_id=m.is_extended_frame, dlc=m.length,
                                    data=p.encode(merged, n), channel=c.bus)
    return scheduled()


# --- the responder ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Rule:
    """On a frame of `on`, send `send` with signals set from the request (scale * its signal +
    offset) or constants; the rest as the plan gives them (start values, counter, checksum)."""
    on: Any           # cantools Message
    send: MessagePlan
    copies: dict[str, tuple[str, float, float]] = field(default_factory=dict)  # target -> (source, scale, offset)
    line: int = 0
    group: int | None = None  # a J1939 request's group: answered from any source (dbc.group_read)
    db: Any = None            # the DBC of `on`: which frames are its (dbc.message_of)

    def answer(self, request: bytes, n: int) -> tuple[Any, bytes]:
        """The n-th answer; UndecodableRequest if the request is not its message, Unanswerable
        if a copied value is one the answer's signal cannot carry."""
        try:
            decoded = decode(self.on, request)
        except Exception as e:  # noqa: BLE001 - cantools' decode errors say what it could not read
            raise UndecodableRequest(str(e)) from None
        values = self.send.values(0.0)
        for target, (source, scale, offset) in self.copies.items():
            if source not in decoded:  # a signal of another page of a multiplexed request
                raise Unanswerable(f"{self.on.name}.{source} is not in this request's page")
            values[target] = decoded[source] * scale + offset
            lo, hi, said = bits_range(self.send.message.get_signal_by_name(target))
            if not lo <= values[target] <= hi:
                raise Unanswerable(f"{self.send.message.name}.{target} from {self.on.name}.{source}: "
                                   f"{values[target]:g} is outside {said}")
        try:
            return self.send.message, self.send.encode(values, n)
        except Exception as e:  # noqa: BLE001 - cantools' encode errors say what it could not encode
            raise Unanswerable(f"{self.send.message.name}: {e}") from None


class UndecodableRequest(ValueError):
    """A request frame its rule's message does not decode."""


class Unanswerable(ValueError):
    """A request whose answer cannot be encoded (a copied value out of the answer signal's range)."""


# --- reading the scenario's values (problems reported, never raised) ---------------------------

Fail = Callable[[list, str], None]
FailFile = Callable[[Path, int, str], None]


def value_problem(signal, value, ids: list[int] | None = None, in_yaml: bool = True) -> str | None:
    """Why a value cannot be this signal's (None if it can); ids: a multiplexer's ids; in_yaml:
    a scenario's value (text that reads as a number is said to be YAML's text)."""
    if isinstance(value, bool):
        said = [str(n) for n in (signal.choices or {}).values() if str(n).lower() in YAML_BOOLS[value]]
        return (f"YAML reads {said[0]} as {str(value).lower()}, not a name of {signal.name}'s value table: "
                f"write '{said[0]}'" if said else f"{value!r} is not a number or a name of {signal.name}'s value table")
    if isinstance(value, str):
        problem = name_problem(signal, value, in_yaml)
        if problem:
            return problem
        value = signal.conversion.choice_to_number(value)
        return None if ids is None or value in ids else \
            f"{value!r} is not one of {signal.name}'s multiplexer ids {ids}"
    if not isinstance(value, int | float) or not math.isfinite(value):
        return f"{value!r} is not a number"
    if ids is not None and value not in ids:  # cantools selects a page by the exact id
        return f"{value:g} is not one of {signal.name}'s multiplexer ids {ids}"
    return range_problem(signal, value)


def read_signal_trace(path: Path, shown: Path, signal, fail_file: FailFile,
                      ids: list[int] | None = None) -> SignalTrace | None:
    """A CSV signal trace (`time_s,value`, an optional header line, # comments); each bad line
    is a problem at its file:line (ids: a multiplexer's ids, see value_problem)."""
    times, values, ok, first = array("d"), [], True, True
    try:  # as a DBC is read: a spreadsheet saves UTF-8 with a byte-order mark, or cp1252
        text = saved_text(path.read_bytes())
    except OSError as e:
        fail_file(shown, 0, f"cannot read: {e.strerror}")
        return None
    for lineno, row in enumerate(csv.reader(text.splitlines()), 1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        header, first = first, False
        if len(row) != 2:
            fail_file(shown, lineno, f"a line is time_s,value ({len(row)} fields)")
            ok = False
            continue
        try:
            t = float(row[0])
        except ValueError:
            if header:  # a header line (time_s,value): only as the first row
                continue
            fail_file(shown, lineno, f"time_s {row[0].strip()!r} is not a number")
            ok = False
            continue
        raw = row[1].strip()
        try:
            value: float | str = float(raw)
        except ValueError:
            value = raw
        problem = value_problem(signal, value, ids, in_yaml=False) if math.isfinite(t) and t >= 0 \
            else "time_s must be >= 0"
        if problem is None and times and t < times[-1]:
            problem = f"time_s {t:g} is before the line above's {times[-1]:g}"
        if problem:
            fail_file(shown, lineno, problem)
            ok = False
            continue
        times.append(t)
        values.append(value)
    if ok and not times:
        fail_file(shown, 1, "no values (lines of time_s,value)")
        return None
    return SignalTrace(path, times, tuple(values)) if ok else None


def source_of(spec, signal, where: list, base: Path, fail: Fail, fail_file: FailFile,
              ids: list[int] | None = None) -> Source | None:
    """A signal's value source from the scenario (ids: a multiplexer's ids, see value_problem)."""
    if isinstance(spec, dict) and "ramp" in spec:
        if ids is not None:  # a ramp passes between the ids: pages cantools cannot encode
            fail([*where, "ramp"], f"{signal.name} is a multiplexer (ids {ids}): give an id, a signal trace "
                 "of ids, or nothing (its pages in turn)")
            return None
        ends = spec["ramp"]
        for i, end in enumerate(ends):
            problem = value_problem(signal, end) if not isinstance(end, str) \
                else (name_problem(signal, end) if text_number(end) else f"{end!r} is not a number")
            if problem:
                fail([*where, "ramp", i], problem)
                return None
        return Ramp(float(ends[0]), float(ends[1]), float(spec["over_s"]))
    if isinstance(spec, dict) and "trace" in spec:
        shown = base / spec["trace"]
        if not shown.is_file():
            fail([*where, "trace"], f"no such file {shown}")
            return None
        return read_signal_trace(shown.resolve(), shown, signal, fail_file, ids)
    problem = value_problem(signal, spec, ids)
    if problem:
        fail(where, problem)
        return None
    return Constant(spec)


def message_plan(message, spec: dict, where: list, base: Path, fail: Fail, fail_file: FailFile,
                 signal_key: Callable[[str], str | None] = lambda name: name,
                 signals_key: str = "signals") -> MessagePlan:
    """A message's plan from a scenario mapping with `signals`, `counters`, `checksums`
    (signal_key: the signal's name in this message of a scenario key, None if the key is another
    message's); every unknown signal, bad value or checksum that cannot be one is a problem."""
    names = {s.name for s in message.signals}

    def local(key: str, at: list) -> str | None:
        name = signal_key(key)
        if name is not None and name not in names:
            fail(at, f"{message.name} has no signal {name!r} (it has {sorted(names)})")
            return None
        return name

    sources: dict[str, Source] = {}
    for key, value in (spec.get(signals_key) or {}).items():
        name = local(key, [*where, signals_key, key])
        if name is not None:
            source = source_of(value, message.get_signal_by_name(name), [*where, signals_key, key], base, fail,
                               fail_file, mux_ids(message, name))
            if source is not None:
                sources[name] = source
    counter = None
    for i, key in enumerate(spec.get("counters") or []):
        name = local(key, [*where, "counters", i])
        if name is None:
            continue
        s = message.get_signal_by_name(name)
        if s.is_multiplexer:
            fail([*where, "counters", i], f"{message.name}.{name} is a multiplexer: it selects pages, "
                 "in turn when not set")
        elif s.is_signed or s.is_float or s.scale != 1 or s.offset != 0:
            fail([*where, "counters", i], f"{message.name}.{name}: a counter is an unsigned integer signal "
                 "(scale 1, offset 0)")
        elif not counter_values(s):
            fail([*where, "counters", i], f"{message.name}.{name}: its DBC range [{s.minimum}|{s.maximum}] "
                 f"holds no value its {s.length} bits carry")
        elif counter is not None:
            fail([*where, "counters", i], f"{message.name} has a counter already ({counter})")
        elif name in sources:
            fail([*where, "counters", i], f"{message.name}.{name} has a value in signals too")
        else:
            counter = name
    checksum = None
    for key, algorithm in (spec.get("checksums") or {}).items():
        name = local(key, [*where, "checksums", key])
        if name is None:
            continue
        s = message.get_signal_by_name(name)
        try:
            if s.is_signed or s.is_float or s.scale != 1 or s.offset != 0:
                raise ValueError("a checksum signal is one unsigned byte (scale 1, offset 0)")
            checksum_byte(message, name)
        except ValueError as e:
            fail([*where, "checksums", key], f"{message.name}.{name}: {e}")
            continue
        if checksum is not None:
            fail([*where, "checksums", key], f"{message.name} has a checksum already ({checksum[0]})")
        elif name in sources or name == counter:
            fail([*where, "checksums", key], f"{message.name}.{name} is a counter or has a value in signals too")
        else:
            checksum = (name, algorithm)
    return MessagePlan(message, sources, counter, checksum, cycle_time_ms(message))  # None: an event message


def carried_nowhere(plan: MessagePlan, where: list, fail: Fail) -> None:
    """A counter or checksum on no page the scenario lets the message send (its multiplexer pinned
    to another page) is a problem: the frames would never carry it."""
    m = plan.message
    if not m.is_multiplexed():
        return
    given = tuple((k, src.value) for k, src in plan.sources.items()
                  if k in multiplexers(m) and isinstance(src, Constant))
    allowed = _pages(m, given)
    for kind, name in (("counters", plan.counter), ("checksums", plan.checksum[0] if plan.checksum else None)):
        if name and not any(on_page(m, name, page) for page in allowed):
            fail([*where, kind], f"{m.name}.{name} is on no page the scenario sends ({', '.join(map(str, given))}): "
                 "no frame would carry it")


def start_value_problems(plan: MessagePlan, where: list, fail: Fail, copied: frozenset[str] = frozenset()) -> None:
    """A signal the scenario leaves at its DBC start value (GenSigStartValue) that its bits cannot
    carry is a problem here, naming it, not an encoding error mid-run (on whichever page); copied:
    a responder's signals set from the request."""
    m = plan.message
    for s in m.signals:
        if s.name in plan.sources or s.name in copied or s.is_multiplexer or s.name == plan.counter or \
                (plan.checksum and s.name == plan.checksum[0]):
            continue
        value = default_value(s)
        lo, hi, said = bits_range(s)
        if isinstance(value, int | float) and not lo <= value <= hi:
            fail(where, f"{m.name}.{s.name}: its start value {value:g} (GenSigStartValue) is outside {said}: "
                 "give it a value in signals")


def _split(key: str) -> tuple[str, str] | None:
    message, dot, signal = key.partition(".")
    return (message, signal) if dot and message and signal else None


def why_not_cyclic(message) -> str:
    """Why the DBC gives a message no cycle of its own (for a node whose messages are all so)."""
    if send_type_cyclic(message.send_type):
        return f"GenMsgCycleTime {message.cycle_time!r}" if message.cycle_time is not None else "no GenMsgCycleTime"
    return f"GenMsgSendType {message.send_type}"


def restbus_plans(db, spec: dict, where: list, base: Path, fail: Fail,
                  fail_file: FailFile) -> tuple[tuple[MessagePlan, ...], tuple[str, ...]]:
    """A restbus ECU's plans: every cyclic message its dbc_node transmits; `signals`,
    `counters`, `checksums` keyed Message.Signal, `cycle_ms` per message (overriding the DBC);
    and the messages left out that it transmits (CAN FD ones), each with why."""
    node = spec["dbc_node"]
    nodes = sorted({n.name for n in db.nodes} | {s for m in db.messages for s in m.senders})  # BU_ may omit senders
    if node not in nodes:
        fail([*where, "dbc_node"], f"the DBC has no node {node!r} (it has {nodes})")
        return (), ()
    sent = [m for m in db.messages if node in m.senders]
    if not sent:
        fail([*where, "dbc_node"], f"{node} transmits no message in the DBC (no BO_ names it as sender)")
        return (), ()
    unsendable: dict[str, str] = {}  # message -> why the bench cannot send it
    for m in sent:
        if why := f"{m.length} data bytes: CAN FD" if too_long_for_can_20(m) else encode_problem(m):
            unsendable[m.name] = why
    left_out = tuple(f"{m.name} ({unsendable[m.name]})" for m in sent  # those it would send
                     if m.name in unsendable and cycle_time_ms(m))
    if len(unsendable) == len(sent):  # cycle_ms would not help
        fail([*where, "dbc_node"], f"{node} transmits nothing the bench can send: "
             + "; ".join(f"{name} ({why})" for name, why in list(unsendable.items())[:8]))
        return (), left_out
    sent = [m for m in sent if m.name not in unsendable]
    by_name = {m.name: m for m in sent}
    for kind in ("signals", "counters", "checksums", "cycle_ms"):
        items = spec.get(kind) or {}
        for i, key in enumerate(items):
            at = [*where, kind, key if isinstance(items, dict) else i]
            name = key if kind == "cycle_ms" else (_split(key) or ("", ""))[0]
            if kind != "cycle_ms" and _split(key) is None:
                fail(at, f"{key!r}: name a signal as Message.Signal")
            elif name in unsendable:
                fail(at, f"{node}'s restbus leaves {name} out: {unsendable[name]}")
            elif name not in by_name:
                known = "the DBC has no message" if name not in {m.name for m in db.messages} \
                    else f"{node} does not transmit" if not too_long_for_can_20(db.get_message_by_name(name)) \
                    else "the bench carries CAN 2.0 frames, not the CAN FD message"
                fail(at, f"{known} {name!r} ({node} transmits {sorted(by_name)})")
    out = []
    for m in sent:
        def key_of(key: str, m=m) -> str | None:
            parts = _split(key)
            return parts[1] if parts and parts[0] == m.name else None
        plan = message_plan(m, spec, where, base, fail, fail_file, key_of)
        cycle = (spec.get("cycle_ms") or {}).get(m.name, plan.cycle_ms)
        if cycle:
            start_value_problems(plan, where, fail)
            carried_nowhere(plan, where, fail)
            out.append(MessagePlan(m, plan.sources, plan.counter, plan.checksum, float(cycle)))
    if not out:
        why = "; ".join(f"{m.name}: {why_not_cyclic(m)}" for m in sent[:8]) + ("; ..." if len(sent) > 8 else "")
        fail([*where, "dbc_node"], f"{node} transmits no cyclic CAN 2.0 message ({why}): give cycle_ms per message")
    return tuple(out), left_out


def _message(db, name: str, at: list, fail: Fail, sent: bool = True):
    """A message the bench can read, or send (sent): the DBC's, CAN 2.0, and one it can encode."""
    try:
        message = db.get_message_by_name(name)
    except KeyError:
        fail(at, f"the DBC has no message {name!r}")
        return None
    if too_long_for_can_20(message):
        fail(at, f"{name} has {message.length} data bytes (CAN FD): the bench carries CAN 2.0 frames, up to 8")
        return None
    if sent and (why := encode_problem(message)):
        fail(at, why)
        return None
    return message


def responder_rules(db, specs: list, where: list, base: Path, fail: Fail, fail_file: FailFile) -> tuple[Rule, ...]:
    """The responder's rules: on each frame of `request`, `send` a message with `set: {signal: value}`, a
    value being a signal of the request (copied), `{from: signal, scale:, offset:}`, or a constant;
    `counters` and `checksums` of the answer as for a restbus message."""
    rules = []
    for i, spec in enumerate(specs):
        at = [*where, i]
        on = _message(db, spec["request"], [*at, "request"], fail, sent=False)
        send = _message(db, spec["send"], [*at, "send"], fail)
        if on is None or send is None:
            continue
        request = {s.name for s in on.signals}
        copies, constants = {}, {}
        for target, value in (spec.get("set") or {}).items():
            copy = {"from": value} if isinstance(value, str) and value in request else value
            if isinstance(copy, dict) and "from" in copy:
                if copy["from"] not in request:
                    fail([*at, "set", target], f"{on.name} has no signal {copy['from']!r} (it has {sorted(request)})")
                elif target not in {s.name for s in send.signals}:
                    fail([*at, "set", target], f"{send.name} has no signal {target!r}")
                else:
                    copies[target] = (copy["from"], float(copy.get("scale", 1)), float(copy.get("offset", 0)))
            else:
                constants[target] = value
        plan = message_plan(send, {**spec, "set": constants}, at, base, fail, fail_file, signals_key="set")
        start_value_problems(plan, at, fail, frozenset(copies))
        carried_nowhere(plan, at, fail)
        rules.append(Rule(on, plan, copies, group=group_read(db, on), db=db))
    return tuple(rules)


def command_plan(db, spec: dict, where: list, base: Path, fail: Fail, fail_file: FailFile) \
        -> tuple[MessagePlan | None, tuple]:
    """A command in signals: its message's plan (signals, counters, checksums, cycle_ms or the
    DBC's cycle) and its schedule ((at_s, signal values, scenario line) per entry)."""
    m = _message(db, spec["message"], [*where, "message"], fail)
    if m is None:
        return None, ()
    plan = message_plan(m, spec, where, base, fail, fail_file)
    carried_nowhere(plan, where, fail)
    cycle = spec.get("cycle_ms", plan.cycle_ms)
    schedule = []
    names = {s.name for s in m.signals}
    for i, entry in enumerate(spec.get("schedule") or []):
        values = {}
        for key, value in (entry.get("signals") or {}).items():
            at = [*where, "schedule", i, "signals", key]
            if key not in names:
                fail(at, f"{m.name} has no signal {key!r} (it has {sorted(names)})")
                continue
            problem = value_problem(m.get_signal_by_name(key), value, mux_ids(m, key))
            if problem:
                fail(at, problem)
            values[key] = value
        schedule.append((float(entry["at_s"]), values, 0))
    # a signal the first entry sets is never at its start value (entries' signals hold after them)
    first_set = frozenset(min(schedule, key=lambda e: e[0])[1]) if schedule else frozenset()
    start_value_problems(plan, where, fail, first_set)
    if not schedule and not cycle:
        fail([*where, "message"], f"{m.name} has no GenMsgCycleTime: give cycle_ms or a schedule")
    return MessagePlan(m, plan.sources, plan.counter, plan.checksum, float(cycle) if cycle else None), \
        tuple(sorted(schedule, key=lambda e: e[0]))
