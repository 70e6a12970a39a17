"""The oracle: matches what went onto the CAN bus with what came out on Zenoh
and computes loss, duplicates, corruption (which bytes), reordering (global
and per id), latency and per-id cycle times. Correct first: every frame is
accounted for, and each failure names the frames and where they came from.

Matching is by content and order, independent of the bridge's own sequence
numbers (a broken bridge must not be able to hide its faults): a Zenoh frame
matches an unmatched CAN frame with the same key (id, flags, dlc, data) —
of those, the one nearest to where the stream has got to (the furthest CAN
frame matched so far), the earlier one on a tie. Real traffic repeats
contents (a status frame every 10 ms, counters that wrap), so "the n-th Zenoh
frame with a key is the n-th CAN frame with it" is wrong as soon as one copy
is lost: every later copy would shift onto its predecessor and the loss would
show up at the end of the run instead of where it happened. Frames left on
the CAN side are lost; Zenoh frames with a key the CAN side had are
duplicates; Zenoh frames with a key it never had are paired with the lost
frame at the same place in the stream, if that one has the same id and length
(corrupted), else counted as unexpected."""
from __future__ import annotations

import bisect
import gc
from array import array
from collections import Counter, defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import wraps
from pathlib import Path

from . import trace, wire
from .capture import Sample
from .errors import TraceError
from .stats import latency_stats, percentile


@dataclass(frozen=True, slots=True)
class Observed:
    frame: wire.Frame
    t_ns: int          # CAN: bus timestamp; Zenoh: receive time
    index: int         # position in its stream
    line: int = 0      # CAN: line in the capture file
    key: str = ""      # Zenoh: key expression of the sample
    seq: int = -1      # Zenoh: bridge sequence number
    bridge_rx_ns: int = 0  # Zenoh: CAN receive time the bridge put in the attachment
    origin: str = "can.log"  # the file `line` refers to


FRAME_CACHE = 1 << 20  # distinct frame contents kept for sharing (then it starts again: only memory is at stake)


def _without_gc(fn):
    """Runs fn with the cyclic collector paused: reading and matching build millions of objects
    and no cycles, and the collector walking them cost a quarter of the analysis's CPU time
    (bench/oracle_scale.py)."""
    @wraps(fn)
    def paused(*args, **kwargs):
        was = gc.isenabled()
        gc.disable()
        try:
            return fn(*args, **kwargs)
        finally:
            if was:
                gc.enable()
    return paused


@_without_gc
def read_candump(path: Path, interface: str | None = None, drops: dict[str, int] | None = None) -> list[Observed]:
    """The frames of a candump -L capture (of one interface), each with its line."""
    return [Observed(frame, t_ns, i, line=lineno)
            for i, (lineno, t_ns, _, frame) in enumerate(trace.iter_candump(path, interface, drops))]


@dataclass(frozen=True)
class SentRecord:
    log_line: int     # line in the send log
    bus: str
    source_line: int  # line in the trace it came from (0: generated)
    t_ns: int
    frame: wire.Frame


def read_sent_log(path: Path) -> list[SentRecord]:
    """An ECU's or the commander's send log. Columns: source line, send time (ns since
    the epoch), the frame in candump form '<bus> <id>#<data>'."""
    out = []
    for lineno, raw in enumerate(open(path), 1):
        if raw.startswith("#") or not raw.strip():
            continue
        fields = raw.rstrip("\n").split("\t")
        if len(fields) != 3:
            raise TraceError(str(path), lineno, f"not a send-log line ({len(fields)} fields, not 3)")
        bus, frame = trace.parse_frame_text(fields[2], str(path), lineno)
        out.append(SentRecord(lineno, bus, int(fields[0]), int(fields[1]), frame))
    return out


def zenoh_frames(samples: Iterable[Sample], key: str) -> tuple[list[Observed], list[str]]:
    """Frames of the samples on key, in arrival order; and problems (bad payloads)."""
    return zenoh_frames_by_key(samples, {key})[0][key]


@_without_gc
def zenoh_frames_by_key(samples: Iterable[Sample], keys: set[str]) \
        -> tuple[dict[str, tuple[list[Observed], list[str]]], set[str]]:
    """In one pass over a capture (iter_zenoh_capture: never all samples in memory at once):
    per key of `keys`, its frames in arrival order and its problems (bad payloads); and every
    key a sample came on."""
    out: dict[str, tuple[list[Observed], list[str]]] = {k: ([], []) for k in keys}
    seen: set[str] = set()
    cache: dict[bytes, wire.Frame] = {}
    for t_ns, sample_key, payload, att in samples:
        seen.add(sample_key)
        if sample_key not in out:
            continue
        frames_on_key, problems = out[sample_key]
        if len(cache) > FRAME_CACHE:
            cache.clear()
        try:
            frames = wire.decode_batch(payload, cache)
            meta = wire.decode_attachment(att) if att is not None else None
        except wire.WireError as e:
            problems.append(f"undecodable sample on {sample_key} at {t_ns}: {e}")
            continue
        for i, f in enumerate(frames):
            frames_on_key.append(Observed(f, t_ns, len(frames_on_key), key=sample_key,
                                          seq=meta.first_seq + i if meta else -1,
                                          bridge_rx_ns=meta.rx_times_ns[i] if meta and i < meta.count else 0))
    return out, seen


def _key(f: wire.Frame) -> tuple:
    return (f.can_id, f.extended, f.remote, f.dlc, f.data)


@dataclass
class Comparison:
    sent: int = 0
    received: int = 0
    matched: list[tuple[Observed, Observed]] = field(default_factory=list)
    lost: list[Observed] = field(default_factory=list)
    duplicates: list[Observed] = field(default_factory=list)
    corrupted: list[tuple[Observed, Observed, list[int]]] = field(default_factory=list)
    unexpected: list[Observed] = field(default_factory=list)
    reordered: list[tuple[Observed, Observed]] = field(default_factory=list)  # (frame, frame it overtook)
    reordered_per_id: int = 0
    latency_ms: array[float] = field(default_factory=lambda: array("d"))  # 8 bytes a frame: an hour's stays small
    lost_in_faults: list[Observed] = field(default_factory=list)  # lost inside a fault window: allowed, counted
    recovery_s: list[float | None] = field(default_factory=list)  # per fault window: end -> first bridged frame
    attachment: dict | None = None  # CAN -> Zenoh: where the bridge's own account disagrees (attachment_check)

    def negative_latencies(self) -> list[tuple[Observed, Observed]]:
        """Matched pairs that arrived before they were sent: the bench's clocks or stamps are wrong."""
        return [(s, r) for s, r in self.matched if r.t_ns < s.t_ns]

    def summary(self) -> dict:
        return {
            "sent": self.sent, "received": self.received, "matched": len(self.matched), "lost": len(self.lost),
            "duplicates": len(self.duplicates), "corrupted": len(self.corrupted),
            "unexpected": len(self.unexpected), "reordered": len(self.reordered),
            "reordered_per_id": self.reordered_per_id, "latency": latency_stats(self.latency_ms),
            "lost_in_faults": len(self.lost_in_faults), "recovery_s": self.recovery_s,
            **({"attachment_disagrees": self.attachment} if self.attachment is not None else {}),
        }


def compare(sent: list[Observed], received: list[Observed]) -> Comparison:
    """sent: CAN frames in bus order; received: Zenoh frames in arrival order."""
    c, _ = _classify(sent, received, None)
    c.attachment = attachment_check(sent, c.matched)
    return c


EXAMPLES = 5  # disagreements listed per kind


def attachment_check(sent: list[Observed], matched: list[tuple[Observed, Observed]]) -> dict:
    """The bridge's own account (the attachment's sequence numbers and CAN receive stamps)
    against the oracle's: reported, never used to match or judge (a broken bridge must not
    hide its faults). can_stamp: the bridge's stamp of a frame is not the bus capture's (at the
    capture's microseconds; with one stamp per frame they are equal). seq: two frames that
    arrived one after the other are numbered further apart (or closer) than the bus had them."""
    rank = {o.index: i for i, o in enumerate(sent)}
    stamps: list[str] = []
    stamp_count, stamp_max_ns = 0, 0
    for s, r in matched:
        if r.bridge_rx_ns and r.bridge_rx_ns // 1000 != s.t_ns // 1000:
            stamp_count += 1
            stamp_max_ns = max(stamp_max_ns, abs(r.bridge_rx_ns - s.t_ns))
            if len(stamps) < EXAMPLES:
                stamps.append(f"{describe(s)}: bridge stamp {(r.bridge_rx_ns - s.t_ns) / 1000:+.3f} us off")
    seqs: list[str] = []
    seq_count = 0
    by_arrival = sorted((p for p in matched if p[1].seq >= 0), key=lambda p: p[1].index)
    for (s0, r0), (s1, r1) in zip(by_arrival, by_arrival[1:], strict=False):
        if r1.seq - r0.seq != rank[s1.index] - rank[s0.index]:
            seq_count += 1
            if len(seqs) < EXAMPLES:
                seqs.append(f"seq {r0.seq} -> {r1.seq} for {describe(s0)} -> {describe(s1)} "
                            f"({rank[s1.index] - rank[s0.index]:+d} on the bus)")
    return {"can_stamp": {"count": stamp_count, "max_us": round(stamp_max_ns / 1000, 3), "examples": stamps},
            "seq": {"count": seq_count, "examples": seqs}}


def compare_commands(commands: list[Observed], bus: list[Observed],
                     sent_by_others: Counter) -> tuple[Comparison, list[Observed]]:
    """Zenoh -> CAN: commands in put order against the bus in bus order. Bus frames that
    other nodes (ECUs) say they sent are theirs and returned; any other bus frame came from
    the bridge: a duplicate of a command, a corrupted command, or unexpected."""
    return _classify(commands, bus, Counter(sent_by_others))


def match_subset(expected: list[Observed], observed: list[Observed]) -> Comparison:
    """Each expected frame against a stream that also carries other traffic (round trip:
    echo answers among everything on the rx key). Only matched and lost are meaningful."""
    c, _ = _classify(expected, observed, _everything())
    c.received = len(c.matched)
    return c


STAMP_SLACK_NS = 5_000_000  # a frame this much "before it was sent" is matched anyway: a bench error, not a loss
BEHIND_SCAN = 4096           # matched copies looked past for a late one (a later frame is a duplicate + a loss)


class _Copies:
    """The sent frames with one key, in stream order, and which of them are matched."""

    def __init__(self) -> None:
        self.frames: list[Observed] = []
        self.indices: list[int] = []
        self.times: list[int] = []
        self.used = bytearray()
        self.head = 0  # every copy before it is matched

    def add(self, o: Observed) -> None:
        self.frames.append(o)
        self.indices.append(o.index)
        self.times.append(o.t_ns)
        self.used.append(0)

    def take(self, frontier: int, t_ns: int) -> Observed | None:
        """The copy a frame received at t_ns is, marked matched (None: it is none of them).
        Only a copy sent by t_ns can be it. Of those, the one with the fewest frames of other
        contents between it and the frontier; on a tie the one ahead (a loss is the simpler
        story than a late frame; within a run of identical frames the earliest one: nothing
        tells them apart). If no copy was sent by t_ns, the next one ahead if it was sent at
        most STAMP_SLACK_NS later: the match shows as a negative latency, a bench error."""
        n = len(self.indices)
        ahead_at = bisect.bisect_right(self.indices, frontier)
        ahead = ahead_at
        while ahead < n and self.used[ahead]:
            ahead += 1
        best = None
        best_distance = None
        if ahead < n and self.times[ahead] <= t_ns:
            best = ahead
            best_distance = (self.indices[ahead] - frontier) - (ahead - ahead_at)
        behind_at = bisect.bisect_left(self.indices, frontier)
        behind = behind_at - 1
        scanned = 0
        while behind >= self.head and scanned < BEHIND_SCAN:
            distance = (frontier - self.indices[behind]) - (behind_at - 1 - behind)
            if best_distance is not None and distance >= best_distance:
                break
            if not self.used[behind] and self.times[behind] <= t_ns:
                best = behind
                break
            behind -= 1
            scanned += 1
        if best is None and ahead < n and self.times[ahead] <= t_ns + STAMP_SLACK_NS:
            best = ahead
        if best is None:
            return None
        self.used[best] = 1
        while self.head < n and self.used[self.head]:
            self.head += 1
        return self.frames[best]

    def __bool__(self) -> bool:
        return self.head < len(self.frames)


class _everything(Counter):
    """An 'explained' budget that explains every frame."""

    def __missing__(self, key):
        return 1 << 62


@_without_gc
def _classify(sent: list[Observed], received: list[Observed],
              explained: Counter | None) -> tuple[Comparison, list[Observed]]:
    c = Comparison(sent=len(sent), received=len(received))
    waiting: dict[tuple, _Copies] = {}
    for s in sent:
        waiting.setdefault(_key(s.frame), _Copies()).add(s)
    seen_keys = set(waiting)
    leftovers: list[Observed] = []
    others: list[Observed] = []
    frontier = -1  # the furthest sent index matched so far
    leftover_frontier: list[int] = []  # where the stream had got to when each leftover arrived
    for r in received:
        k = _key(r.frame)
        copies = waiting.get(k)
        nearest = copies.take(frontier, r.t_ns) if copies else None
        if nearest is not None:
            frontier = max(frontier, nearest.index)
            c.matched.append((nearest, r))
        elif explained is not None and explained[k] > 0:
            explained[k] -= 1
            others.append(r)
        elif k in seen_keys:
            c.duplicates.append(r)
        else:
            leftovers.append(r)
            leftover_frontier.append(frontier)
    if explained is not None:
        c.received -= len(others)
    lost = sorted((copies.frames[i] for copies in waiting.values() for i in range(copies.head, len(copies.frames))
                   if not copies.used[i]), key=lambda o: o.index)
    # corruption: an unknown frame where a lost frame of the same id and length was due: the
    # one nearest to where the stream had got to (ahead of it on a tie)
    lost_by_id: dict[tuple, list[Observed]] = defaultdict(list)
    for s in lost:
        lost_by_id[(s.frame.can_id, s.frame.extended, s.frame.dlc)].append(s)
    corrupted_sent = set()
    for r, at in zip(leftovers, leftover_frontier, strict=True):
        candidates = lost_by_id.get((r.frame.can_id, r.frame.extended, r.frame.dlc))
        if candidates:
            i = bisect.bisect_right([o.index for o in candidates], at)
            if i == len(candidates) or (i > 0 and at - candidates[i - 1].index < candidates[i].index - at):
                i -= 1
            s = candidates.pop(i)
            corrupted_sent.add(s.index)
            diff = [i for i, (a, b) in enumerate(zip(s.frame.data, r.frame.data, strict=False)) if a != b]
            c.corrupted.append((s, r, diff))
        else:
            c.unexpected.append(r)
    c.lost = [s for s in lost if s.index not in corrupted_sent]
    # reordering: received order against sent order, globally and per id
    last_by_id: dict[tuple, int] = {}
    previous: tuple[Observed, Observed] | None = None
    for s, r in sorted(c.matched, key=lambda p: p[1].index):
        if previous and s.index < previous[0].index:
            c.reordered.append((s, previous[0]))
        ident = (s.frame.can_id, s.frame.extended)
        if ident in last_by_id and s.index < last_by_id[ident]:
            c.reordered_per_id += 1
        last_by_id[ident] = max(s.index, last_by_id.get(ident, -1))
        if not previous or s.index > previous[0].index:
            previous = (s, r)
        c.latency_ms.append((r.t_ns - s.t_ns) / 1e6)
    return c, others


FAULT_LEAD_NS = 1_000_000_000  # frames this long before a fault may still be in flight (queues, TCP buffers)
# Reconnection settles after its first frame: measured in the one-hour soak, zenohd 1.10.2 and a client
# re-establishing their session lost 1 sample 3 ms after the first one got through (once in 11 restarts).
FAULT_SETTLE_NS = 1_000_000_000


def apply_fault_windows(c: Comparison, windows: list[tuple[int, int]]) -> None:
    """Loss inside a fault window is the fault's, not the bridge's: a lost frame sent between
    a fault's start (minus FAULT_LEAD_NS) and FAULT_SETTLE_NS after the first frame bridged
    after the fault's end moves from lost to lost_in_faults. recovery_s per window: fault
    end -> arrival of that first frame (None: nothing sent after the fault got through)."""
    matched = sorted(c.matched, key=lambda p: p[0].t_ns)
    allowed = []
    for start_ns, end_ns in windows:
        first = next(((s, r) for s, r in matched if s.t_ns >= end_ns), None)
        c.recovery_s.append(round((first[1].t_ns - end_ns) / 1e9, 3) if first else None)
        allowed.append((start_ns - FAULT_LEAD_NS, first[0].t_ns + FAULT_SETTLE_NS if first else end_ns))
    c.lost_in_faults = [o for o in c.lost if any(a <= o.t_ns < b for a, b in allowed)]
    c.lost = [o for o in c.lost if not any(a <= o.t_ns < b for a, b in allowed)]


def cycle_times(frames: list[Observed]) -> dict[str, dict]:
    """Per id: count and cycle time statistics (ms) of a CAN stream."""
    by_id: dict[str, list[int]] = defaultdict(list)
    for o in frames:
        by_id[wire.id_hex(o.frame.can_id, o.frame.extended)].append(o.t_ns)
    out = {}
    for ident, times in sorted(by_id.items()):
        gaps = [(b - a) / 1e6 for a, b in zip(times, times[1:], strict=False)]
        out[ident] = {"count": len(times), "cycle_p50_ms": percentile(gaps, 0.5),
                      "cycle_min_ms": min(gaps) if gaps else None, "cycle_max_ms": max(gaps) if gaps else None}
    return out


def frame_key(f: wire.Frame) -> tuple:
    return _key(f)


def describe(o: Observed) -> str:
    if o.line:
        where = f"{o.origin}:{o.line}"
    elif o.key:
        where = f"zenoh #{o.index} seq {o.seq}"
    else:
        where = f"{o.origin} #{o.index}"
    return f"{o.frame.candump(o.key or 'bus').split(' ', 1)[1]} ({where})"
