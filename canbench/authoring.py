"""Help for writing scenarios from a recorded trace: a per-id summary (count,
rate, inferred cycle time, jitter, bus load) and a scenario scaffold that
replays the trace with gates derived from it; with a DBC, per-message signal
statistics and proposed signal ranges and DBC cycle times, marked for review."""
from __future__ import annotations

import filecmp
import math
import os
import re
import shutil
import statistics
import tempfile
from array import array
from collections import defaultdict
from dataclasses import dataclass, field
from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal
from pathlib import Path
from typing import Any

import yaml

from . import scenario
from .errors import InputError, TraceError
from .trace import STREAM_CACHE, format_line, iter_trace, where_in
from .wire import id_hex

# An id is periodic when nearly all its gaps sit near the median gap: a median alone
# (or its absolute deviation) also "finds" a cycle in two interleaved streams of one id
# (gaps 1, 9, 1, 9 ms) or in bursts, and a gate on such a median flips with one frame.
STEADY_PCT = 10  # a gap within +-10 % of the cycle is steady
PERIODIC_STEADY_PCT = 90  # ... and an id with at least 90 % steady gaps is periodic
# A logger's jitter (a USB adapter's stamps: 10 ms gaps spread over 7.6..12.4 ms) puts a fifth to a
# half of a periodic id's gaps beyond +-STEADY_PCT, while every one stays near the cycle: such an id
# is periodic too when at least PERIODIC_STEADY_PCT of its gaps are within +-NEAR_PCT (the scaffold's
# tolerance) and at least half within +-STEADY_PCT (so its median is not the edge of two clusters:
# 8 and 12 ms alternating, 1 and 9 ms interleaved, stay out)
NEAR_PCT = 20


def frame_bits_worst(dlc: int, extended: bool, remote: bool = False) -> int:
    """Worst-case stuffed length of a classic CAN frame incl. 3 bits interframe space
    (Davis, Burns et al., 'CAN schedulability analysis revisited')."""
    n = 0 if remote else dlc
    return (8 * n + 64 + (54 + 8 * n - 1) // 4 if extended else 8 * n + 44 + (34 + 8 * n - 1) // 4) + 3


@dataclass
class IdSummary:
    ident: str
    extended: bool
    count: int
    dlc: int
    cycle_ms: float | None
    jitter_ms: float | None  # median absolute deviation of the gaps
    remote: int
    steady_pct: float | None = None  # share of the gaps within STEADY_PCT of the cycle
    interface: str | None = None  # the trace's interface (channel) it was recorded on
    near_pct: float | None = None  # share of the gaps within NEAR_PCT of the cycle
    max_gap_ms: float | None = None  # the longest gap
    min_dlc: int | None = None  # the smallest dlc, when not every frame had `dlc` (the largest)


@dataclass
class TraceSummary:
    path: Path
    frames: int
    span_s: float
    interfaces: list[str]  # as the trace names them (none: a format without channels)
    ids: list[IdSummary]  # per interface and id: each interface is a bus of its own
    load_pct: float  # the busiest interface's
    bitrate: int
    loads: dict[str, float] = field(default_factory=dict)  # per interface, of a trace of several
    longest_gap_s: float = 0.0  # between two frames of the trace (any ids)
    longest_gap_line: int = 0  # the frame after it
    drops: dict[str, int] = field(default_factory=dict)  # per interface: frames candump -d says the kernel dropped
    left_out: dict[str, list[int]] = field(default_factory=dict)  # error and CAN FD frames: lines (frame numbers)

    def table(self) -> str:
        several = len(self.interfaces) > 1
        where = ", ".join(self.interfaces) if self.interfaces else "one interface the trace does not name"
        load = (", ".join(f"{i} {pct:.1f}%" for i, pct in self.loads.items()) if several
                else f"{self.load_pct:.1f}%")
        lines = [f"{self.path}: {self.frames} frames over {self.span_s:.3f} s on {where}; "
                 f"bus load {load} of {self.bitrate // 1000} kbit/s (worst-case stuffing)"
                 + (f"; longest gap {self.longest_gap_s:.3f} s (before {where_in(self.path, self.longest_gap_line)})"
                    if self.longest_gap_line else ""),
                 *([f"  {dropped_note(self.drops)}: the gaps and cycles below count its holes"]
                   if self.drops else []),
                 *([f"  {left_out_note(self.path, self.left_out)}"] if self.left_out else []),
                 f"  {'interface  ' if several else ''}{'id':>8}  {'frames':>7}  {'dlc':>3}  {'cycle ms':>9}  "
                 f"{'jitter ms':>9}  {'steady %':>8}  remote"]
        for s in self.ids:
            cycle = f"{s.cycle_ms:9.2f}" if s.cycle_ms is not None else f"{'-':>9}"
            jitter = f"{s.jitter_ms:9.3f}" if s.jitter_ms is not None else f"{'-':>9}"
            steady = f"{s.steady_pct:8.0f}" if s.steady_pct is not None else f"{'-':>8}"
            iface = f"{s.interface or '-':<9}  " if several else ""
            dlcs = f"{s.min_dlc}-{s.dlc}" if s.min_dlc is not None else str(s.dlc)  # several: what a DBC decodes
            lines.append(f"  {iface}{s.ident:>8}  {s.count:>7}  {dlcs:>3}  {cycle}  {jitter}  {steady}  {s.remote}")
        return "\n".join(lines)


def left_out_note(path: Path, left_out: dict[str, list[int]]) -> str:
    """What a recording's error and CAN FD frames mean for what is read from it."""
    said = " and ".join(f"{len(lines)} {kind}{'s' if len(lines) != 1 else ''} (the first: {where_in(path, lines[0])})"
                        for kind, lines in sorted(left_out.items()))
    return f"{said} of {path.name} not replayed: the bridge carries CAN 2.0 data and remote frames only"


def dropped_note(drops: dict[str, int]) -> str:
    """What a recording's DROPCOUNT lines mean for what is read from it."""
    said = ", ".join(f"{n} frame{'s' if n != 1 else ''} on {iface}" for iface, n in sorted(drops.items()))
    return f"INCOMPLETE: candump says the kernel dropped {said} while recording (DROPCOUNT lines)"


@dataclass
class _IdState:
    """One id's running state in one pass: its gaps (ms, 8 bytes each: a 1M-frame trace 8 MiB)."""
    count: int = 0
    dlc: int = 0
    min_dlc: int = 8
    remote: int = 0
    last_ns: int | None = None
    gaps: array = field(default_factory=lambda: array("d"))


def summarise(path: Path, bitrate: int = 500_000) -> TraceSummary:
    """Per interface and id: count, dlc, cycle (median gap), jitter, steadiness; bus load per
    interface. One pass over the trace, state per id only (not its frames)."""
    by_id: dict[tuple[str | None, int, bool], _IdState] = defaultdict(_IdState)
    bits: dict[str | None, int] = defaultdict(int)
    spans: dict[str | None, list[int]] = {}  # per interface: its first and last stamp, the first frame's bits
    frames = 0
    first_ns = last_ns = None
    gap_ns, gap_line = 0, 0
    drops: dict[str, int] = {}
    left_out: dict[str, list[int]] = {}
    for line, t_ns, iface, frame in iter_trace(path, cache_size=STREAM_CACHE, drops=drops, left_out=left_out):
        frames += 1
        state = by_id[(iface, frame.can_id, frame.extended)]
        if state.last_ns is not None:
            state.gaps.append((t_ns - state.last_ns) / 1e6)
        state.last_ns = t_ns
        state.count += 1
        state.dlc = max(state.dlc, frame.dlc)
        state.min_dlc = min(state.min_dlc, frame.dlc)
        state.remote += frame.remote
        frame_bits = frame_bits_worst(frame.dlc, frame.extended, frame.remote)
        bits[iface] += frame_bits
        own = spans.setdefault(iface, [t_ns, t_ns, frame_bits])
        if t_ns < own[0]:
            own[0], own[2] = t_ns, frame_bits
        own[1] = max(own[1], t_ns)
        # the span and gaps of the merged timeline: a log of several interfaces is in time order
        # per interface only, so its first and last lines need not be its first and last frames
        if last_ns is not None and t_ns - last_ns > gap_ns:
            gap_ns, gap_line = t_ns - last_ns, line
        first_ns = t_ns if first_ns is None else min(first_ns, t_ns)
        last_ns = t_ns if last_ns is None else max(last_ns, t_ns)
    if first_ns is None or last_ns is None:
        raise TraceError(str(path), None, f"no CAN 2.0 frames in trace: {left_out_note(path, left_out)}" if left_out
                         else "no frames in trace")
    span = (last_ns - first_ns) / 1e9
    ids = []
    for (iface, can_id, extended), state in sorted(by_id.items(), key=lambda kv: (str(kv[0][0]), *kv[0][1:])):
        gaps = state.gaps
        cycle = statistics.median(gaps) if gaps else None
        jitter = statistics.median(abs(g - cycle) for g in gaps) if gaps and cycle is not None else None
        steady = (100 * sum(abs(g - cycle) <= cycle * STEADY_PCT / 100 for g in gaps) / len(gaps)
                  if gaps and cycle else None)
        near = (100 * sum(abs(g - cycle) <= cycle * NEAR_PCT / 100 for g in gaps) / len(gaps)
                if gaps and cycle else None)
        ids.append(IdSummary(id_hex(can_id, extended), extended, state.count, state.dlc,
                             None if cycle is None else round(cycle, 6), jitter, state.remote, steady, iface,
                             near, max(gaps) if gaps else None, state.min_dlc if state.min_dlc < state.dlc else None))
    # each interface's load over its own span: one recorded from later on (or stopped earlier) is
    # not diluted by the time the other interfaces were recorded alone
    # (a frame is stamped as it ends: the span holds the first frame's time on the wire too, so three
    # frames back to back are a full bus, not 162 %)
    own_span = {i: (last - first) / 1e9 + first_bits / bitrate for i, (first, last, first_bits) in spans.items()}
    loads = {str(i): 100 * b / bitrate / own_span[i] if own_span[i] > 0 else 0.0
             for i, b in sorted(bits.items(), key=str) if i is not None}
    total_load = 100 * sum(bits.values()) / bitrate / span if span > 0 else 0.0
    return TraceSummary(path, frames, span, sorted(loads), ids, max(loads.values(), default=total_load), bitrate,
                        loads, gap_ns / 1e9, gap_line, drops, left_out)


# ---- signals of a trace, with a DBC (canbench summarise --dbc, canbench scaffold --dbc) ----

SIGNAL_MARGIN_PCT = 10  # a proposed range: the observed min/max widened by this % of the span
CHOICES_SEEN_MAX = 32   # value-table names kept per signal (a proposal lists what it saw)


@dataclass
class SignalStats:
    name: str
    unit: str
    count: int = 0
    min: float | None = None
    max: float | None = None
    total: float = 0.0
    names: set[str] | None = None  # value-table names seen (None: the signal has no value table)
    unnamed: bool = False  # a value its value table has no name for was seen
    nonfinite: int = 0  # NaN or infinite values (a float signal's bits): counted, kept out of min, max, mean

    def add(self, value: float, name: str | None) -> None:
        self.count += 1
        if not math.isfinite(value):  # one NaN would make min, max and mean NaN, and no range holds it
            self.nonfinite += 1
            return
        self.total += value
        self.min = value if self.min is None else min(self.min, value)
        self.max = value if self.max is None else max(self.max, value)
        if self.names is not None:
            if name is None:
                self.unnamed = True
            elif len(self.names) < CHOICES_SEEN_MAX:
                self.names.add(name)


@dataclass
class MessageStats:
    name: str
    ident: str
    frames: int = 0
    undecodable: int = 0
    cycle_ms: float | None = None  # the DBC's GenMsgCycleTime of a cyclic message
    signals: dict[str, SignalStats] | None = None


@dataclass
class SignalSummary:
    path: Path
    dbc: Path
    messages: list[MessageStats]
    unknown_ids: dict[str, int]  # frames of ids the DBC lacks
    interfaces: list[str] = field(default_factory=list)  # the trace's: statistics over all of them together

    def table(self) -> str:
        together = f" (over {', '.join(self.interfaces)} together)" if len(self.interfaces) > 1 else ""
        lines = [f"{self.path}: signals decoded with {self.dbc} (cantools){together}: {len(self.messages)} messages "
                 f"of the DBC seen, {sum(self.unknown_ids.values())} frames of {len(self.unknown_ids)} ids it lacks"
                 + (f" ({', '.join(sorted(self.unknown_ids)[:10])}{', ...' if len(self.unknown_ids) > 10 else ''})"
                    if self.unknown_ids else "")]
        for m in self.messages:
            cycle = f", DBC cycle {m.cycle_ms:g} ms" if m.cycle_ms else ""
            bad = f", {m.undecodable} undecodable" if m.undecodable else ""
            lines.append(f"  {m.name} ({m.ident}): {m.frames} frames{cycle}{bad}")
            lines.append(f"    {'signal':<28}  {'values':>7}  {'min':>12}  {'max':>12}  {'mean':>12}  "
                         "unit / names seen")
            for sig in (m.signals or {}).values():
                odd = f" ({sig.nonfinite} NaN or infinite)" if sig.nonfinite else ""
                if sig.min is None or sig.max is None:
                    dash = f"{'-':>12}"
                    lines.append(f"    {sig.name:<28}  {sig.count:>7}  {dash}  {dash}  {dash}  {sig.unit}{odd}")
                    continue
                names = f" {sorted(sig.names)}" if sig.names else ""
                digits = _digits_apart(sig.min, sig.max)
                lines.append(f"    {sig.name:<28}  {sig.count:>7}  {sig.min:>12.{digits}g}  {sig.max:>12.{digits}g}  "
                             f"{sig.total / (sig.count - sig.nonfinite):>12.{digits}g}  {sig.unit}{names}{odd}")
        return "\n".join(lines)


def _digits_apart(a: float, b: float) -> int:
    """Significant digits that show two numbers apart when they differ (6 at least, 17 at most)."""
    digits = 6
    while digits < 17 and a != b and f"{a:.{digits}g}" == f"{b:.{digits}g}":
        digits += 1
    return digits


def summarise_signals(path: Path, dbc_path: Path, lenient: bool = False) -> SignalSummary:
    """Per message of the DBC seen in the trace: frames, and per signal count, min, max, mean
    (physical values, as cantools decodes them) and the value-table names seen. One pass, state
    per signal only. lenient: a DBC cantools' strict mode refuses is read as written."""
    from .dbc import cycle_time_ms, decode, message_of, read_dbc
    db = read_dbc(dbc_path, lenient)
    stats: dict[str, MessageStats] = {}
    unknown: dict[str, int] = defaultdict(int)
    interfaces: set[str] = set()
    for _, _, iface, frame in iter_trace(path, cache_size=STREAM_CACHE, left_out={}):  # summarise says them
        if iface is not None:
            interfaces.add(iface)
        message = message_of(db, frame)
        if message is None:
            unknown[id_hex(frame.can_id, frame.extended)] += 1
            continue
        if frame.remote:
            continue
        ms = stats.get(message.name)
        if ms is None:
            ms = stats[message.name] = MessageStats(
                message.name, id_hex(message.frame_id, message.is_extended_frame), cycle_ms=cycle_time_ms(message),
                signals={s.name: SignalStats(s.name, s.unit or "", names=set() if s.choices else None)
                         for s in message.signals})
        ms.frames += 1
        try:
            values = decode(message, frame.data)
        except Exception:  # noqa: BLE001 - counted: a frame the DBC does not describe
            ms.undecodable += 1
            continue
        signals = {s.name: s for s in message.signals}
        for name, value in values.items():
            if isinstance(value, int | float) and ms.signals is not None and name in ms.signals:
                choice = None
                if signals[name].choices:
                    raw = signals[name].conversion.scaled_to_raw(value)
                    choice = signals[name].choices.get(raw)
                ms.signals[name].add(float(value), None if choice is None else str(choice))
    return SignalSummary(path, dbc_path, sorted(stats.values(), key=lambda x: x.ident), dict(unknown),
                         sorted(interfaces))


def proposed_signals(summary: SignalSummary) -> list[tuple[str, dict[str, list | int], str, bool]]:
    """(Message.Signal, expectation, why, usable) proposed from what the trace showed: value-table
    signals whose every value had a name as one_of those names, others a range of the observed
    min/max widened by SIGNAL_MARGIN_PCT of the span (of the value when constant), within the
    signal's DBC limits. Not usable: a range wholly outside what the DBC lets the signal carry
    (the scenario would refuse it; the DBC, or its decoding of this trace, is wrong)."""
    from .dbc import load_dbc, value_range
    db = load_dbc(summary.dbc)  # read (and accepted) by summarise_signals
    out: list[tuple[str, dict[str, list | int], str, bool]] = []
    for m in summary.messages:
        message = db.get_message_by_name(m.name)
        for sig in (m.signals or {}).values():
            key = f"{m.name}.{sig.name}"
            if m.undecodable:  # a gate counts each such frame a violation: the trace would fail itself
                out.append((key, {"present": 1}, f"not gated: {m.undecodable} of {m.name}'s {m.frames} frames do not "
                            f"decode with the DBC (a length other than its {message.length} bytes?)", False))
                continue
            if sig.min is None or sig.max is None:
                if sig.nonfinite:
                    out.append((key, {"present": 1}, f"not gated: its {sig.nonfinite} values were all NaN or "
                                "infinite", False))
                continue
            digits = _digits_apart(sig.min, sig.max)
            seen = (f"seen {sig.min:.{digits}g}..{sig.max:.{digits}g}{' ' + sig.unit if sig.unit else ''} in "
                    f"{sig.count} values")
            if sig.names and not sig.unnamed and len(sig.names) < CHOICES_SEEN_MAX:
                out.append((key, {"one_of": sorted(sig.names)}, f"value-table names seen in {sig.count} values", True))
                continue
            span = sig.max - sig.min
            margin = span * SIGNAL_MARGIN_PCT / 100 if span else (abs(sig.max) * SIGNAL_MARGIN_PCT / 100 or 1.0)
            low, high = sig.min - margin, sig.max + margin
            dbc_signal = message.get_signal_by_name(sig.name)
            if dbc_signal.minimum is not None and sig.min >= dbc_signal.minimum:
                low = max(low, float(dbc_signal.minimum))
            if dbc_signal.maximum is not None and sig.max <= dbc_signal.maximum:
                high = min(high, float(dbc_signal.maximum))
            beyond = [f"{word} the DBC's {limit:g}" for word, limit, out_of in (
                ("below", dbc_signal.minimum, dbc_signal.minimum is not None and sig.min < dbc_signal.minimum),
                ("above", dbc_signal.maximum, dbc_signal.maximum is not None and sig.max > dbc_signal.maximum))
                if out_of]
            lo, hi, _ = value_range(dbc_signal)
            low, high = _round(low, up=False), _round(high, up=True)
            outside = high < lo or low > hi
            out.append((key, {"range": [low, high]},
                        seen + (f" ({' and '.join(beyond)}: is the DBC right?)" if beyond else "")
                        + (f"; not gated: wholly outside the [{lo:g}, {hi:g}] the DBC allows" if outside
                           else f"; not gated: {sig.nonfinite} NaN or infinite, which no range passes"
                           if sig.nonfinite else ""),
                        not outside and not sig.nonfinite))
    return out


def _round(v: float, up: bool) -> float | int:
    """A range's end at 6 significant digits, rounded outward: the one at or below v (the low end)
    or at or above it (up), so that the range still holds every value it was made from (an
    odometer seen at 123456.7..123456.8 km, rounded to the nearest: [123457, 123457] held neither)."""
    r = float(v)
    if math.isfinite(v) and v != 0:
        d = Decimal(repr(v))
        r = float(d.quantize(Decimal(1).scaleb(d.adjusted() - 5), rounding=ROUND_CEILING if up else ROUND_FLOOR))
    return int(r) if r.is_integer() and abs(r) < 1e15 else r


def _signals_yaml(summary: SignalSummary) -> str:
    """expect.signals proposed from the trace, as YAML text under expect (indented by 2), each
    entry marked for review."""
    proposals = proposed_signals(summary)
    if not proposals:
        return ""
    lines = [f"  # PROPOSED, REVIEW EACH: from what {summary.path.name} showed, decoded with {summary.dbc.name}:",
             f"  # observed min/max widened by {SIGNAL_MARGIN_PCT}% of the span (within the DBC's limits), value-table",
             "  # signals as one_of the names seen. A trace is not a specification: set what the ECU must do,",
             "  # drop what is not a requirement (counters, checksums).",
             "  signals:" if any(usable for *_, usable in proposals) else "  # signals:"]
    for key, spec, why, usable in proposals:
        # allow_unicode: a value-table name as the DBC writes it (Geöffnet, not "Ge\\xF6ffnet")
        body = yaml.safe_dump(spec, default_flow_style=True, width=1000, allow_unicode=True).strip()
        lines.append(f"    {'' if usable else '# '}{key}: {body}  # review: {why}")
    return "\n".join(lines) + "\n"


DURATION_MARGIN_S = 5  # a scaffolded duration_s: 1.5 x the trace's span + this, at least 10 s
BUS_NAME = re.compile(r"^vcan[0-9]+$")


def _bus_number(bus: str) -> int:
    return int(bus.removeprefix("vcan"))


def bus_names(interfaces: list[str]) -> dict[str, str]:
    """The scenario bus of each interface a trace records: its own name when it is one the
    bench takes (vcanN), else the lowest vcanN no other interface has, in the interfaces' order."""
    taken = {i for i in interfaces if BUS_NAME.match(i)}
    free = (f"vcan{n}" for n in range(len(interfaces) + len(taken)) if f"vcan{n}" not in taken)
    return {i: i if i in taken else next(free) for i in interfaces}


def copy_in(source: Path, copy: Path, said: str | None = None) -> Path:
    """source copied to copy, which may already hold the same bytes (a scaffold run again); one
    with other bytes is another scenario's file there, never overwritten (an InputError naming
    the source, or what `said` calls it)."""
    if copy.exists():
        if not filecmp.cmp(source, copy, shallow=False):
            raise InputError(str(copy), None, f"exists with other contents than {said or source} (another "
                             "scenario's file?): scaffold into another folder, or rename the recording")
        return copy
    copy.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, copy)
    return copy


def classic_only(trace: Path, bus: str, folder: Path) -> Path:
    """A one-interface trace as a candump -L file of its CAN 2.0 data and remote frames, on bus:
    what its replay ECU can send (not error frames, nor CAN FD frames)."""
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as work:  # copy_in when whole
        part = Path(work) / f"{trace.stem}.classic.log"
        with open(part, "w") as out:
            for _, t_ns, _, frame in iter_trace(trace, cache_size=STREAM_CACHE, left_out={}):
                out.write(format_line(t_ns, bus, frame) + "\n")
        return copy_in(part, folder / part.name, f"the CAN 2.0 frames of {trace}")


def split_trace(trace: Path, buses: dict[str, str], folder: Path) -> tuple[dict[str, Path], dict[str, float]]:
    """A trace of several interfaces as one candump -L file per interface (its frames only, in
    order, the frame on the interface's bus): what each bus's replay ECU sends; and each one's
    first frame after the trace's first (s): its start_offset_s, so the buses keep their
    recorded timing to one another (a replay starts at its own first frame). One pass."""
    folder.mkdir(parents=True, exist_ok=True)
    first: dict[str, int] = {}
    with tempfile.TemporaryDirectory(dir=folder) as work:  # copy_in each part when whole
        parts = {iface: Path(work) / f"{trace.stem}.{iface}.log" for iface in buses}
        outs = {iface: open(path, "w") for iface, path in parts.items()}
        try:
            for _, t_ns, iface, frame in iter_trace(trace, cache_size=STREAM_CACHE, left_out={}):
                first.setdefault(str(iface), t_ns)
                outs[str(iface)].write(format_line(t_ns, buses[str(iface)], frame) + "\n")
        finally:
            for out in outs.values():
                out.close()
        paths = {iface: copy_in(part, folder / part.name, f"the {iface} frames of {trace}")
                 for iface, part in parts.items()}
    start = min(first.values())
    return paths, {iface: round((t_ns - start) / 1e9, 6) for iface, t_ns in first.items()}


def dbc_cycles_of(s: TraceSummary, dbc_path: Path) -> dict[str, tuple[Any, float]]:
    """trace id -> (its message, the DBC's cycle in ms), for the trace's ids that are a cyclic
    message of the DBC (its own id, or a J1939 group's from another source: dbc.message_of)."""
    from .dbc import cycle_of_id, load_dbc
    db = load_dbc(dbc_path)
    return {i.ident: found for i in s.ids if (found := cycle_of_id(db, int(i.ident, 16), i.extended))}


def _dbc_cycles_off(s: TraceSummary, dbc_cycles: dict[str, tuple[Any, float]],
                    tolerance_pct: float) -> dict[str, tuple[float, float]]:
    """id -> (the trace's median cycle, the DBC's) for the trace's ids of a cyclic message of the
    DBC (dbc_cycles) that it sends at another cycle (beyond tolerance_pct; the median over its
    interfaces), and for those of an event-periodic message (EventPeriodic, ...: from_dbc judges
    its longest gap on the bus against the DBC's cycle) whose longest gap in the trace is beyond
    the DBC's cycle + tolerance_pct (a frame the car or its logger missed): the gate from_dbc
    writes for them would fail the trace itself."""
    from .dbc import send_type_at_most
    seen: dict[str, list[float]] = {}
    longest: dict[str, float] = {}
    for i in s.ids:
        if i.cycle_ms:
            seen.setdefault(i.ident, []).append(i.cycle_ms)
        if i.max_gap_ms is not None:
            longest[i.ident] = max(longest.get(i.ident, 0.0), i.max_gap_ms)
    out = {}
    for ident, (message, cycle) in dbc_cycles.items():
        if ident in seen:
            median = statistics.median(seen[ident])
            if abs(median - cycle) > cycle * tolerance_pct / 100 or (
                    send_type_at_most(message.send_type)
                    and longest.get(ident, 0.0) > cycle * (1 + tolerance_pct / 100)):
                out[ident] = (round(median, 3), cycle)
    return out


def _no_one_cycle(s: TraceSummary, dbc_cycles: dict[str, tuple[Any, float]]) -> list[str]:
    """The ids of a cyclic message of the DBC (dbc_cycles) that the trace does not send at one
    cycle on every interface where it has 5 frames or more: a median gap of 0 on one (sent twice a
    cycle under one logger stamp), or cycles beyond STEADY_PCT of the first's (as gated_cycles
    judges them) on another. from_dbc would judge each against the DBC's one cycle on every bus,
    and fail the trace itself."""
    return sorted(ident for ident, on in _judged_by_id(s).items()
                  if ident in dbc_cycles and (any(not i.cycle_ms for i in on) or not _one_cycle(on)))


def periodic(i: IdSummary) -> bool:
    """Whether an id's gaps show one cycle: PERIODIC_STEADY_PCT of them within +-STEADY_PCT of
    it, or (a logger's jitter) within +-NEAR_PCT with half of them within +-STEADY_PCT."""
    if i.steady_pct is None:
        return False
    return i.steady_pct >= PERIODIC_STEADY_PCT or (
        i.near_pct is not None and i.near_pct >= PERIODIC_STEADY_PCT and i.steady_pct >= 50)


def _judged_by_id(s: TraceSummary) -> dict[str, list[IdSummary]]:
    """Each id's summaries on the interfaces where it has 5 frames or more (the ones judged)."""
    judged: dict[str, list[IdSummary]] = defaultdict(list)
    for i in s.ids:
        if i.count >= 5:
            judged[i.ident].append(i)
    return judged


def _one_cycle(on: list[IdSummary]) -> bool:
    """Whether the interfaces' cycles of an id are one: each within STEADY_PCT of the first's."""
    first = on[0].cycle_ms or 0.0
    return all(abs((i.cycle_ms or 0.0) - first) <= first * STEADY_PCT / 100 for i in on)


def gated_cycles(s: TraceSummary) -> tuple[dict[str, float], list[str]]:
    """cycle_time.ids from the trace: each id periodic (>= 5 frames, PERIODIC_STEADY_PCT of its
    gaps steady) on every interface where it has 5 frames or more, with one cycle (within
    STEADY_PCT) on all of them; and the periodic ids left out because their interfaces disagree."""
    cycles: dict[str, float] = {}
    disagree: list[str] = []
    for ident, on in _judged_by_id(s).items():
        steady = [i for i in on if i.cycle_ms and periodic(i)]
        if not steady:
            continue
        if len(steady) < len(on) or not _one_cycle(steady):
            disagree.append(ident)
            continue
        cycles[ident] = round(statistics.median(i.cycle_ms or 0.0 for i in steady), 3)
    return cycles, disagree


def scaffold(trace: Path, name: str, scenario_path: Path, bitrate: int = 500_000, dbc: Path | None = None,
             dbc_lenient: bool = False) -> str:
    """A scenario replaying the trace, with gates a first run should pass; YAML text.
    The bench mounts only the scenario's directory into its containers, so a trace from
    elsewhere is copied to <scenario dir>/traces/ (and a DBC to <scenario dir>/dbc/). With a
    DBC: cycle times from it (from_dbc) and proposed signal ranges, marked for review;
    dbc_lenient: a DBC cantools' strict mode refuses is read as written (dbc_strict: false)."""
    s = summarise(trace, bitrate)
    limit = scenario.schema()["properties"]["duration_s"]["maximum"]
    if s.span_s + DURATION_MARGIN_S > limit:
        raise TraceError(str(trace), None, f"spans {s.span_s:.0f} s (its longest gap {s.longest_gap_s:.0f} s, before "
                         f"{where_in(trace, s.longest_gap_line)}): a scenario runs at most {limit} s; cut the trace")
    buses = bus_names(s.interfaces)
    bus_limit = scenario.schema()["properties"]["buses"]["maxItems"]
    if len(buses) > bus_limit:
        raise TraceError(str(trace), None, f"{len(buses)} interfaces ({', '.join(s.interfaces)}): a scenario has at "
                         f"most {bus_limit} buses; split the trace")
    signal_summary = summarise_signals(trace, dbc, dbc_lenient) if dbc is not None else None
    home = scenario_path.resolve().parent
    if dbc is not None and not dbc.resolve().is_relative_to(home):
        dbc = copy_in(dbc, home / "dbc" / dbc.name)
    notes = ""
    if len(buses) > 1:  # one bus per recorded interface, each replayed from its own part of the trace
        traces, offsets = split_trace(trace, buses, home / "traces")
        ecus = [{"name": f"recorded-{bus}", "bus": bus, "trace": os.path.relpath(traces[iface], home)}
                | ({"start_offset_s": offsets[iface]} if offsets[iface] else {}) for iface, bus in buses.items()]
        notes += (f"# The trace's interfaces {', '.join(f'{i} -> {b}' for i, b in buses.items())}: one bus and one "
                  f"replay ECU each (traces/{trace.stem}.<interface>.log, candump -L).\n")
    else:
        bus = next(iter(buses.values()), "vcan0")
        replayed = trace
        if s.left_out:
            replayed = classic_only(trace, bus, home / "traces")
        elif not trace.resolve().is_relative_to(home):
            replayed = copy_in(trace, home / "traces" / trace.name)
        ecus = [{"name": "recorded", "bus": bus, "trace": os.path.relpath(replayed.resolve(), home)}]
    if s.drops:
        notes += f"# {dropped_note(s.drops)}: the proposed cycles are read across its holes.\n"
    if s.left_out:
        notes += (f"# Left out: {left_out_note(trace, s.left_out)}; the replay sends the rest "
                  f"({', '.join(str(e['trace']) for e in ecus)}).\n")
    cycles, disagree = gated_cycles(s)
    if disagree:
        notes += (f"# Not gated in cycle_time.ids: {', '.join(disagree[:10])}{', ...' if len(disagree) > 10 else ''} "
                  "(periodic on one interface, not with that cycle on another: the gate is per id on every bus).\n")
    load = (", ".join(f"{buses[i]} {pct:.0f}%" for i, pct in s.loads.items()) if len(buses) > 1
            else f"{s.load_pct:.0f}%")
    doc = {
        "name": name,
        "description": f"Replay of {trace.name} ({s.frames} frames, {s.span_s:.1f} s, "
                       f"{len({(i.ident, i.extended) for i in s.ids})} ids, {load} load at {bitrate // 1000} kbit/s).",
        "duration_s": min(limit, max(10, int(s.span_s * 1.5) + DURATION_MARGIN_S)),
        "buses": [{"name": bus} for bus in (sorted(set(buses.values()), key=_bus_number) or ["vcan0"])],
        "ecus": ecus,
        "bridge": {"mode": "client", "publish_period_ms": 0},
        "expect": {
            "integrity": True, "ordering": True, "loss_budget": 0,
            "latency": {"can_to_zenoh": {"p50_ms": 5, "max_regression_pct": 50}},
            "cycle_time": {"tolerance_pct": 20, "ids": cycles},
        },
    }
    header = (f"# Scaffolded by `canbench scaffold` from {trace.name}: review the gates, then run\n"
              f"#   make test SCENARIO={scenario_path}\n"
              f"{notes}"
              f"# Periodic ids (cycle inferred from the trace, >= {PERIODIC_STEADY_PCT}% of the gaps within "
              f"+-{STEADY_PCT}% of it, or within +-{NEAR_PCT}% with half within +-{STEADY_PCT}%: a logger's "
              "jitter) are gated in cycle_time.ids.\n")
    if dbc is not None and signal_summary is not None:
        from .dbc import load_dbc, strict_problem
        as_written = strict_problem(load_dbc(dbc))
        given = [("dbc", os.path.relpath(dbc.resolve(), home))] + ([("dbc_strict", False)] if as_written else [])
        doc = {k: v for key, value in doc.items()
               for k, v in ([(key, value), *given] if key == "duration_s" else [(key, value)])}
        if as_written:
            header += (f"# REVIEW: dbc_strict: false, as --dbc-lenient asked: the DBC has {as_written}. Each such "
                       "message is read signal by signal; the bench does not send it.\n")
        dbc_cycles = dbc_cycles_of(s, dbc)
        unsure = _no_one_cycle(s, dbc_cycles)
        if unsure:  # from_dbc would judge these against the DBC's cycle on every bus: the trace's own cycles
            header += (f"# Not cycle_time.from_dbc: the trace sends {', '.join(unsure[:10])}"
                       f"{', ...' if len(unsure) > 10 else ''} at no one cycle on every interface (interfaces that "
                       "disagree, or several frames under one logger stamp), which from_dbc would judge against the "
                       "DBC's cycle on every bus; cycle_time.ids holds the trace's periodic ids (REVIEW: the DBC's "
                       "cycles are in `canbench summarise --dbc`).\n")
            dbc_cycles = {}
        from_dbc = set(dbc_cycles)
        if from_dbc:  # the database's cycles; ids: keeps only the periodic ids it has no cycle for
            expect: dict = doc["expect"]  # type: ignore[assignment]
            tolerance = expect["cycle_time"]["tolerance_pct"]
            ids = {k: v for k, v in expect["cycle_time"]["ids"].items() if k not in from_dbc}
            # where the recorded car sends a message at another cycle than its DBC says (another
            # variant, an event-periodic message's events), the trace's cycle: the gate judges the
            # bridge against the bus, and the car is what the bus replays
            overridden = _dbc_cycles_off(s, dbc_cycles, tolerance)
            ids |= {ident: trace_cycle for ident, (trace_cycle, _) in overridden.items()}
            expect["cycle_time"] = {"from_dbc": True, "tolerance_pct": tolerance} | ({"ids": ids} if ids else {})
            header += (f"# cycle_time.from_dbc: the DBC's GenMsgCycleTime for the trace's {len(from_dbc)} ids of its "
                       "cyclic messages (REVIEW: the trace's own cycles are in `canbench summarise`).\n")
            if overridden:
                shown = [f"{ident} every {trace_cycle:g} ms (the DBC: {dbc_cycle:g})"
                         for ident, (trace_cycle, dbc_cycle) in sorted(overridden.items())]
                header += (f"# REVIEW: the trace's cycle in cycle_time.ids where it is not the DBC's +-{tolerance}%: "
                           f"{', '.join(shown[:10])}{', ...' if len(shown) > 10 else ''}.\n")
        return header + yaml.safe_dump(doc, sort_keys=False) + _signals_yaml(signal_summary)
    return header + yaml.safe_dump(doc, sort_keys=False)

