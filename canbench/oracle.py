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
show up at the end of the run instead of where it happened. A frame of a
backlog that may be a duplicate rather than the next copy it took is held in
doubt until the frames after it tell (_Doubt). Frames left on the CAN side are
lost; Zenoh frames with a key the CAN side had are duplicates; Zenoh frames
with a key it never had are paired with the lost frame at the same place in
the stream, if that one has the same id and length (corrupted), else counted
as unexpected.

One pass over both streams in time order, keeping a window: a bus frame can be
matched by a Zenoh frame that arrived at most MATCH_WINDOW_NS after its stamp,
so memory is bounded by the traffic of a window, not by the length of the run
(compare_stream; compare keeps every frame for the checks and the report)."""
from __future__ import annotations

import bisect
import gc
from array import array
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import wraps
from pathlib import Path

from . import trace, wire
from .capture import Sample
from .distribution import Distribution
from .errors import TraceError


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
STREAM_FRAME_CACHE = 1 << 14  # the same for the bounded readers (iter_candump_frames, iter_zenoh_frames): ~4 MiB


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


def iter_candump_frames(path: Path, interface: str | None = None,
                        drops: dict[str, int] | None = None) -> Iterator[Observed]:
    """read_candump's frames one at a time (compare_stream: never the whole capture in memory)."""
    for i, (lineno, t_ns, _, frame) in enumerate(trace.iter_candump(path, interface, drops,
                                                                    cache_size=STREAM_FRAME_CACHE)):
        yield Observed(frame, t_ns, i, line=lineno)


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


def iter_zenoh_frames(samples: Iterable[Sample], key: str, problems: list[str] | None = None) -> Iterator[Observed]:
    """zenoh_frames' frames on key one at a time, in arrival order; bad payloads appended to problems."""
    cache: dict[bytes, wire.Frame] = {}
    n = 0
    for t_ns, sample_key, payload, att in samples:
        if sample_key != key:
            continue
        if len(cache) > STREAM_FRAME_CACHE:
            cache.clear()
        try:
            frames = wire.decode_batch(payload, cache)
            meta = wire.decode_attachment(att) if att is not None else None
        except wire.WireError as e:
            if problems is not None:
                problems.append(f"undecodable sample on {sample_key} at {t_ns}: {e}")
            continue
        for i, f in enumerate(frames):
            yield Observed(f, t_ns, n, key=sample_key, seq=meta.first_seq + i if meta else -1,
                           bridge_rx_ns=meta.rx_times_ns[i] if meta and i < meta.count else 0)
            n += 1


def _key(f: wire.Frame) -> tuple:
    return (f.can_id, f.extended, f.remote, f.dlc, f.data)


# A bus frame is matched by a Zenoh frame that arrived at most MATCH_WINDOW_NS after it: the
# analysis keeps only that window of the bus capture (memory bounded by the traffic of a window,
# not by the run). An older frame still unmatched is lost; a frame that arrives later than the
# window is not its copy (lost, and the late arrival unexpected, or a duplicate if a copy of its
# content is in the window). 20 s: the longest a frame can legitimately wait is a link outage
# shorter than the Zenoh lease (10 s: longer ones drop the session and its queue) plus TCP's
# retransmission backoff after it (up to another ~3 s), the lead and settle time of a fault
# window (1 s each) around it, with margin; every scenario's latency gate is far below (p50 25 ms).
MATCH_WINDOW_NS = 20_000_000_000
FAILURES_KEPT = 1000  # compare_stream: frames kept per kind of failure (all are counted)
EXAMPLES = 5  # attachment disagreements listed per kind


@dataclass
class Comparison:
    sent: int = 0
    received: int = 0
    matched: list[tuple[Observed, Observed]] = field(default_factory=list)  # compare_stream: not kept
    lost: list[Observed] = field(default_factory=list)
    duplicates: list[Observed] = field(default_factory=list)
    corrupted: list[tuple[Observed, Observed, list[int]]] = field(default_factory=list)
    unexpected: list[Observed] = field(default_factory=list)
    reordered: list[tuple[Observed, Observed]] = field(default_factory=list)  # (frame, frame it overtook)
    reordered_per_id: int = 0
    latency: Distribution = field(default_factory=Distribution)  # bounded (canbench.distribution)
    lost_in_faults: list[Observed] = field(default_factory=list)  # lost inside a fault window: allowed, counted
    recovery_s: list[float | None] = field(default_factory=list)  # per fault window: end -> first bridged frame
    attachment: dict | None = None  # CAN -> Zenoh: where the bridge's own account disagrees
    negative: list[tuple[Observed, Observed]] = field(default_factory=list)  # matched, arrived before sent
    counts: Counter = field(default_factory=Counter)  # per kind, all of them (the lists above may be capped)

    @property
    def latency_ms(self) -> array[float]:
        """The latencies (ms) in arrival order; past canbench.distribution.EXACT_VALUES, a uniform sample."""
        return self.latency.values

    def negative_latencies(self) -> list[tuple[Observed, Observed]]:
        """Matched pairs that arrived before they were sent: the bench's clocks or stamps are wrong."""
        return self.negative

    def summary(self) -> dict:
        n = self.counts
        return {
            "sent": self.sent, "received": self.received, "matched": n["matched"], "lost": n["lost"],
            "duplicates": n["duplicates"], "corrupted": n["corrupted"],
            "unexpected": n["unexpected"], "reordered": n["reordered"],
            "reordered_per_id": self.reordered_per_id, "latency": self.latency.stats(),
            "lost_in_faults": n["lost_in_faults"], "recovery_s": self.recovery_s,
            # the frame after which backlogs' duplicates were no longer weighed (oracle.REMATCH_SHARE)
            **({"doubts_budget_spent_at": n["doubts_budget_spent_at"]} if n["doubts_budget_spent_at"] else {}),
            **({"attachment_disagrees": self.attachment} if self.attachment is not None else {}),
        }


def compare(sent: Iterable[Observed], received: Iterable[Observed],
            windows: list[tuple[int, int]] | None = None, cuts: list[tuple[int, int]] | None = None) -> Comparison:
    """sent: CAN frames in bus order; received: Zenoh frames in arrival order. Every frame of
    every kind kept (the matched pairs too); windows: fault windows (apply_fault_windows); cuts:
    those of faults that cut the bridge's link (an outage's doubt looks only there: _outage_copy)."""
    return _classify(sent, received, None, windows=windows, cuts=cuts, attachment=True)[0]


def compare_stream(sent: Iterable[Observed], received: Iterable[Observed],
                   windows: list[tuple[int, int]] | None = None, keep: int = FAILURES_KEPT,
                   on_match: Callable[[Observed, Observed], None] | None = None,
                   cuts: list[tuple[int, int]] | None = None) -> Comparison:
    """compare() in bounded memory, for captures of any length read as they go (iter_candump_frames,
    iter_zenoh_frames): the same verdicts, counts and latencies; the matched pairs are not kept
    (on_match sees each), and `keep` frames per kind of failure are."""
    return _classify(sent, received, None, windows=windows, cuts=cuts, attachment=True, keep=keep,
                     keep_matched=False, on_match=on_match)[0]


def compare_commands(commands: list[Observed], bus: list[Observed],
                     sent_by_others: Counter) -> tuple[Comparison, list[Observed]]:
    """Zenoh -> CAN: commands in put order against the bus in bus order. Bus frames that
    other nodes (ECUs) say they sent are theirs and returned; any other bus frame came from
    the bridge: a duplicate of a command, a corrupted command, or unexpected."""
    return _classify(commands, bus, Counter(sent_by_others))


def match_subset(expected: list[Observed], observed: list[Observed], window_ns: int | None = None) -> Comparison:
    """Each expected frame against a stream that also carries other traffic (round trip:
    echo answers among everything on the rx key). Only matched and lost are meaningful.
    No window by default: both lists are in memory, and a caller may match by order alone
    (every expected frame stamped 0, as validity's send-order check does)."""
    c, _ = _classify(expected, observed, _everything(), window_ns=window_ns)
    c.received = c.counts["matched"]
    return c


STAMP_SLACK_NS = 5_000_000  # a frame this much "before it was sent" is matched anyway: a bench error, not a loss
DUPLICATE_PACE = 10  # ... unless it came within 1/this of its copies' cycle after the last one (_Copies.take)
DOUBT_BACKLOGS = 4  # backlogs a doubtful frame's stories are followed across while the greedy one breaks
DOUBT_FRAMES = 4096  # ... and received frames at most (each matched again after it)
OUTAGE_HOLD = 2  # cycles of its content an outage's doubt is held at least
RECENT = 64  # matches per block of the recent latency range (an outage's doubt: _outage_copy)
BACKLOG_PACE = 1.25  # a backlog comes at least this many times faster than it was sent (backlog_end in _classify)
BACKLOG_LIVE = 2  # ... and where it ends is followed by live frames (the jumped one and one at least)
LIVE_TAIL = 16  # ... and its last frames came at the pace they were sent, not faster (a backlog still draining)
QUEUED_NS = 1_000_000  # ... a live frame this much later than the latency before the fault waited in a queue
LATE_ONLY_DOUBTS = 4  # doubts with no later copy (only a backlog's end may tell) per fault the greedy match
#                      keeps, at most: each matches the frames after it again (a link throttled in the
#                      fault: every frame late and none lost would open one after the other)
REMATCH_SHARE = 2  # frames matched again for doubts, at most this many per frame received (+ REMATCH_FLOOR):
REMATCH_FLOOR = 4 * DOUBT_FRAMES  # past that the run's rest is matched greedily, so the cost stays a few
#                                   times the greedy match's whatever the traffic (stalls full of duplicates)
BEHIND_SCAN = 4096           # matched copies looked past for a late one (a later frame is a duplicate + a loss)
LOAD_TRIM_NS = 1_000_000_000  # how far past its window a frame may stay while the bus capture is read ahead
_END = 1 << 62               # a time after every stamp: the end of both streams
_COMPACT = 16                # evicted copies a _Copies may keep at its front (and at most as many as live ones)


class _Copies:
    """The sent frames with one key still in the window, in stream order, and which of them
    are matched. Positions before `start` are evicted (gone from the window)."""

    __slots__ = ("key", "frames", "indices", "times", "ranks", "used", "head", "start", "arrived")

    def __init__(self, key: tuple) -> None:
        self.key = key
        self.frames: list[Observed | None] = []
        self.indices: list[int] = []
        self.times: list[int] = []
        self.ranks: list[int] = []  # position in the sent stream (index: position on the bus)
        self.used = bytearray()
        self.head = 0   # every copy before it is matched or evicted
        self.start = 0  # every copy before it is evicted
        self.arrived: int | None = None  # when the last received frame with this key arrived

    def add(self, o: Observed, rank: int) -> None:
        self.frames.append(o)
        self.indices.append(o.index)
        self.times.append(o.t_ns)
        self.ranks.append(rank)
        self.used.append(0)

    def take(self, frontier: int, t_ns: int, may_doubt: bool = False) -> int | None:
        """The copy a frame received at t_ns is, marked matched (None: it is none of them).
        Only a copy sent by t_ns can be it. Of those, the one with the fewest frames of other
        contents between it and the frontier; on a tie the one ahead (a loss is the simpler
        story than a late frame; within a run of identical frames the earliest one: nothing
        tells them apart). If no copy was sent by t_ns, the next one ahead if it was sent at
        most STAMP_SLACK_NS later: the match shows as a negative latency, a bench error; but not
        when the frame came within a tenth of that copy's cycle after the last one with this key
        and that one was not early itself: a frame published twice (a duplicate), which taking
        the next copy would shift every later copy onto its predecessor (a fast constant frame:
        all reordered, all "early"). A frame early by its stamp alone arrives at the pace its
        copies were sent, and frames of one early sample follow an early one: both stay bench
        errors. Returns the copy's position (frames[position]); with may_doubt, ~position when
        the frame may be a duplicate instead (_Doubt): it came at a duplicate's pace and took a
        copy ahead with frames of other contents between, none of them received yet."""
        arrived, self.arrived = self.arrived, t_ns
        n = len(self.indices)
        indices, used, times = self.indices, self.used, self.times
        ahead_at = bisect.bisect_right(indices, frontier, self.start)
        ahead = ahead_at
        while ahead < n and used[ahead]:
            ahead += 1
        best = None
        best_distance = None
        if ahead < n and times[ahead] <= t_ns:
            best = ahead
            best_distance = (indices[ahead] - frontier) - (ahead - ahead_at)
        behind_at = bisect.bisect_left(indices, frontier, self.start, ahead_at)
        behind = behind_at - 1
        scanned = 0
        head = self.head
        while behind >= head and scanned < BEHIND_SCAN:
            distance = (frontier - indices[behind]) - (behind_at - 1 - behind)
            if best_distance is not None and distance >= best_distance:
                break
            if not used[behind] and times[behind] <= t_ns:
                best = behind
                break
            behind -= 1
            scanned += 1
        if best is None and ahead < n and times[ahead] <= t_ns + STAMP_SLACK_NS and \
                not (arrived is not None and ahead > self.start and
                     DUPLICATE_PACE * (t_ns - arrived) < times[ahead] - times[ahead - 1]):
            best = ahead
            self.arrived = None  # early: its arrival says nothing of the pace
        if best is None:
            return None
        used[best] = 1
        while head < n and used[head]:
            head += 1
        self.head = head
        if may_doubt and best == ahead and best > self.start and arrived is not None and \
                times[best] <= t_ns and indices[best] - frontier - (best - ahead_at) > 1 and \
                DUPLICATE_PACE * (t_ns - arrived) < times[best] - times[best - 1]:
            return ~best
        return best

    def at(self, index: int) -> int:
        """The position of the copy at bus position index (positions move when evict compacts)."""
        return bisect.bisect_left(self.indices, index, self.start)

    def mark(self, index: int, matched: bool) -> None:
        """Marks the copy at bus position index matched or not (a match undone, or done again)."""
        at = self.at(index)
        self.used[at] = matched
        if not matched:
            self.head = min(self.head, at)
        elif at == self.head:
            head, n = at, len(self.used)
            while head < n and self.used[head]:
                head += 1
            self.head = head

    def free_between(self, after: int, before: int, t_ns: int, marked: set[int]) -> int | None:
        """The bus position of the first copy after `after` and before `before`, sent by t_ns,
        not matched or matched only since (marked)."""
        indices, used, times = self.indices, self.used, self.times
        at = bisect.bisect_right(indices, after, self.start)
        while at < len(indices) and indices[at] < before:
            if (not used[at] or indices[at] in marked) and times[at] <= t_ns:
                return indices[at]
            at += 1
        return None

    def evict(self) -> Observed | None:
        """Drops the oldest copy from the window; returns it if it was never matched (lost)."""
        at = self.start
        o = self.frames[at]
        lost = not self.used[at]
        self.frames[at] = None
        self.used[at] = 1
        self.start = at = at + 1
        n = len(self.used)
        head = max(self.head, at)
        while head < n and self.used[head]:
            head += 1
        self.head = head
        if at >= _COMPACT and 2 * at >= n:
            for column in (self.frames, self.indices, self.times, self.ranks, self.used):
                del column[:at]
            self.head -= at
            self.start = 0
        return o if lost else None

    def live(self) -> bool:
        return self.start < len(self.used)

    def __bool__(self) -> bool:
        return self.head < len(self.frames)


_MATCHED, _DUPLICATE, _THEIRS, _LEFT = range(4)  # a verdict: (kind, received, copy, rank or frontier)


class _Doubt:
    """A received frame that took the next copy of its content, sent after frames of other
    contents not received yet, at a duplicate's pace (_Copies.take): that copy, having overtaken
    them, or a duplicate of the copy before (a frame of a backlog published twice). The greedy
    match goes on meanwhile, its verdicts held back (queue, in arrival order) and its marks noted,
    to be undone. `reach` follows the stream as if the frame were a duplicate (the furthest frame
    sent before its copy received since): a frame past that copy's place first says it was the
    copy; its content again first makes it `suspect`. The greedy story then has every later copy
    of the contents between one place on, which breaks where the backlog ends (a frame read
    behind, a copy not sent yet); both stories are matched until its content comes at its own
    pace again with no new break, and the duplicate taken only if it is the better story
    (duplicate_story in _classify)."""

    __slots__ = ("frame", "copies", "index", "frontier", "reach", "suspect", "inner", "cycle", "backlogs", "faults",
                 "oldest", "queue", "marks", "marked", "arrived", "late", "until", "recent", "outage", "ended",
                 "bounded")

    def __init__(self, r: Observed, copies: _Copies, at: int, frontier: int) -> None:
        s = copies.frames[at]
        assert s is not None
        self.frame = r
        self.copies = copies
        self.index = s.index      # the copy it took
        self.frontier = frontier  # where the stream was before it
        self.reach = frontier
        self.suspect = False
        self.inner = False  # a frame since was doubtful too (matched again once it is resolved)
        self.cycle = copies.times[at] - copies.times[at - 1]  # of its content's copies
        self.backlogs = 0  # ends of backlogs the greedy match broke at, followed while suspect
        self.faults = 0    # the greedy match's faults at the last of them
        self.oldest = s.t_ns      # the earliest copy marked since: undone only while in the window
        self.queue: list[tuple[int, Observed, Observed | None, int]] = []
        self.marks: list[tuple[_Copies, int]] = []
        self.marked: set[int] = set()
        # each content's pace before it (its own: it arrived, a copy or a duplicate)
        self.arrived: dict[int, tuple[_Copies, int | None]] = {id(copies): (copies, r.t_ns)}
        self.late: int | None = None  # an outage's doubt (_outage_copy): the copy it may be instead
        self.until = 0  # an outage's doubt: weighed no earlier (a second backlog right after the first)
        self.recent = 0  # an outage's doubt: the recent latency range when it opened (before the fault)
        self.outage = False  # an outage's doubt (late: None if only a backlog's end may tell, backlog_end)
        self.ended = 0  # an outage's doubt: when the fault it is in ended
        self.bounded = False  # an outage's doubt weighed at the bound (DOUBT_FRAMES, the window), not its pace

    def undo(self) -> None:
        """The marks since it undone, each content's pace as before it."""
        for copies, index in self.marks:
            copies.mark(index, False)
        for copies, arrived in self.arrived.values():
            copies.arrived = arrived
        self.marks = []


def _cycle(times: list[int], at: int) -> int:
    """The cycle of a content's copies at position `at` (it and the next are in the window): the
    longer of the gaps around it, so that two identical frames sent back to back (a burst) do
    not make a cycle of their 0.1 ms."""
    return max(times[at + 1] - times[at], times[at] - times[at - 1] if at > 0 else 0)


def _outage_copy(copies: _Copies, at: int, t_ns: int, recent_ns: int,
                 cuts: list[tuple[int, int]]) -> tuple[int | None, int] | None:
    """A frame that took the copy at position `at` may instead be a later copy of its content, the
    ones between lost in an outage (a cut link, a router restarted): the bus index of the earliest
    copy sent by its arrival whose latency is within the recent range (recent_ns, the highest of
    the last matches: a batch's earliest frame), when the taken one's is past it by more than half the content's
    cycle, with frames of other contents sent between them (none received yet: the taken copy is
    ahead of every match), and the copies between them sent around a fault that cut the link (cuts:
    start - FAULT_LEAD_NS to end + FAULT_SETTLE_NS, where their loss is the fault's), and the latest
    such end + FAULT_SETTLE_NS (the doubt is weighed no earlier). No such copy (None, the copy around
    the fault): the frame may still be the first of a backlog whose queue overflowed (backlog_end in
    _classify). None: no such doubt. Only there:
    elsewhere a lasting rise of latency with nothing lost reads the same on repeating frames, and
    the greedy match reads that one right (docs/bench.md, "The oracle")."""
    times, indices, used = copies.times, copies.indices, copies.used
    if at + 1 >= len(times):
        return None
    half_cycle = _cycle(times, at) // 2
    if t_ns - times[at] <= recent_ns + half_cycle:
        return None
    late = bisect.bisect_left(times, t_ns - recent_ns - half_cycle, at + 1)  # the earliest one in range
    # none, or no frame of another content between (a run of identical frames): no outage's story
    found = late < len(times) and times[late] <= t_ns and not used[late] and \
        indices[late] - indices[at] - (late - at) >= 1
    last = times[late] if found else times[at]
    ends = [end for start, end in cuts if times[at] < end + FAULT_SETTLE_NS and last > start - FAULT_LEAD_NS]
    if not ends:
        return None
    return indices[late] if found else None, max(ends) + FAULT_SETTLE_NS


def _faults(queue: list[tuple[int, Observed, Observed | None, int]], top: int) -> int:
    """A story's faults, to weigh it against another of the same received frames: each frame it
    matched to no copy (a duplicate), behind one received before it (reordered; top: the furthest
    matched before) or to a copy not sent yet. Not the copies it left: a backlog's are still to come."""
    n = 0
    for kind, r, s, _ in queue:
        if kind == _MATCHED:
            assert s is not None
            if s.index < top:
                n += 1
            else:
                top = s.index
            if r.t_ns < s.t_ns:
                n += 1
        elif kind == _DUPLICATE:
            n += 1
    return n


class _everything(Counter):
    """An 'explained' budget that explains every frame."""

    def __missing__(self, key):
        return 1 << 62


class _Faults:
    """Fault windows applied as the pass goes (the rule of apply_fault_windows): per window the
    first frame bridged after its end (the earliest sent, of those matched), and where each
    lost frame goes once it is final."""

    def __init__(self, windows: list[tuple[int, int]]) -> None:
        self.windows = windows
        self.first: list[tuple[int, int] | None] = [None] * len(windows)  # (sent, received) stamps
        self.waiting: list[list[Observed]] = [[] for _ in windows]  # lost after a window nothing got through yet

    def matched(self, s: Observed, r: Observed, c: Comparison, keep: int | None) -> None:
        for i, (_, end) in enumerate(self.windows):
            if s.t_ns >= end:
                first = self.first[i]
                if first is None or s.t_ns < first[0]:
                    self.first[i] = (s.t_ns, r.t_ns)
                    for o in self.waiting[i]:  # something got through: the window reaches past them
                        _note(c, c.lost_in_faults, o, "lost_in_faults", keep)
                    self.waiting[i] = []

    def lost(self, o: Observed, c: Comparison, keep: int | None) -> None:
        """o is final: nothing sent before it will be matched any more."""
        waiting = None
        for i, (start, end) in enumerate(self.windows):
            if o.t_ns < start - FAULT_LEAD_NS:
                continue
            first = self.first[i]
            if o.t_ns < end or (first is not None and o.t_ns < first[0] + FAULT_SETTLE_NS):
                _note(c, c.lost_in_faults, o, "lost_in_faults", keep)
                return
            if first is None:
                waiting = i  # inside if anything ever gets through after this window
        if waiting is not None:
            self.waiting[waiting].append(o)
        else:
            _note(c, c.lost, o, "lost", keep)

    def finish(self, c: Comparison, keep: int | None) -> None:
        for i, (_, end) in enumerate(self.windows):
            first = self.first[i]
            c.recovery_s.append(round((first[1] - end) / 1e9, 3) if first else None)
            for o in self.waiting[i]:
                _note(c, c.lost, o, "lost", keep)


def _note(c: Comparison, where: list, item, kind: str, keep: int | None) -> None:
    c.counts[kind] += 1
    if keep is None or len(where) < keep:
        where.append(item)


@_without_gc
def _classify(sent: Iterable[Observed], received: Iterable[Observed], explained: Counter | None, *,
              windows: list[tuple[int, int]] | None = None, cuts: list[tuple[int, int]] | None = None,
              attachment: bool = False, keep: int | None = None,
              keep_matched: bool = True, on_match: Callable[[Observed, Observed], None] | None = None,
              window_ns: int | None = MATCH_WINDOW_NS) -> tuple[Comparison, list[Observed]]:
    """One pass in time order: a sent frame enters the window when the received stream gets to
    STAMP_SLACK_NS before its stamp, leaves it window_ns after its stamp (lost if unmatched);
    a received frame no copy in the window matches waits until every lost frame it could be a
    corruption of is final (corrupted or unexpected), a lost frame until no such frame waits."""
    c = Comparison()
    slack = STAMP_SLACK_NS
    waiting: dict[tuple, _Copies] = {}
    window: deque[_Copies] = deque()  # the copies each frame of the window belongs to, in stream order
    window_t: deque[int] = deque()
    others: list[Observed] = []
    faults = _Faults(windows or [])
    leftovers: deque[tuple[Observed, int]] = deque()  # (frame, frontier when it arrived), arrival order
    lost_fifo: deque[Observed] = deque()  # lost frames a waiting leftover may still be a corruption of
    pool: dict[tuple, tuple[list[int], list[int], list[Observed]]] = {}  # by (id, ext, dlc): index, t, frame
    paired: set[int] = set()  # indexes of lost frames paired with a corrupted one, still in lost_fifo
    frontier = -1  # the furthest sent index matched so far
    horizon = -(1 << 62)  # every sent frame stamped before it has left the window
    rank = 0
    sent_it = iter(sent)
    nxt = next(sent_it, None)
    last_by_id: dict[tuple, int] = {}
    previous: Observed | None = None  # the matched sent frame with the highest index so far
    stamp_count = stamp_max_ns = seq_count = 0
    stamps: list[str] = []
    seqs: list[str] = []
    previous_seq: tuple[Observed, Observed, int] | None = None
    latency = c.latency
    counts = c.counts

    def release() -> None:
        """Lost frames no waiting leftover can be a corruption of are final."""
        oldest = leftovers[0][0].t_ns - (window_ns or _END) if leftovers else None
        while lost_fifo and (oldest is None or lost_fifo[0].t_ns < oldest):
            o = lost_fifo.popleft()
            if o.index in paired:
                paired.discard(o.index)
                continue
            idx, ts, frames = pool[(o.frame.can_id, o.frame.extended, o.frame.dlc)]
            at = bisect.bisect_left(idx, o.index)
            del idx[at], ts[at], frames[at]
            faults.lost(o, c, keep)

    def decide(r: Observed, at: int) -> None:
        """r matched no copy: a corruption of the lost frame of its id and length sent within the
        window before it nearest to where the stream had got to (ahead on a tie), else unexpected."""
        entry = pool.get((r.frame.can_id, r.frame.extended, r.frame.dlc))
        hi = bisect.bisect_right(entry[1], r.t_ns + slack) if entry else 0
        if not hi:
            _note(c, c.unexpected, r, "unexpected", keep)
            return
        idx, ts, frames = entry  # type: ignore[misc]
        i = bisect.bisect_right(idx, at, 0, hi)
        if i == hi or (i > 0 and at - idx[i - 1] < idx[i] - at):
            i -= 1
        s = frames[i]
        del idx[i], ts[i], frames[i]
        paired.add(s.index)
        diff = [b for b, (x, y) in enumerate(zip(s.frame.data, r.frame.data, strict=False)) if x != y]
        _note(c, c.corrupted, (s, r, diff), "corrupted", keep)

    def advance(now: int) -> None:
        nonlocal horizon
        limit = now if now == _END else now - window_ns if window_ns is not None else horizon
        if limit <= horizon:
            return
        horizon = limit
        while window_t and window_t[0] < limit:
            window_t.popleft()
            copies = window.popleft()
            o = copies.evict()
            if o is not None:
                lost_fifo.append(o)
                idx, ts, frames = pool.setdefault((o.frame.can_id, o.frame.extended, o.frame.dlc), ([], [], []))
                at = bisect.bisect_right(idx, o.index)
                idx.insert(at, o.index)
                ts.insert(at, o.t_ns)
                frames.insert(at, o)
            if not copies.live():
                del waiting[copies.key]
        while leftovers and leftovers[0][0].t_ns + slack < limit:
            release()
            decide(*leftovers.popleft())
        release()

    # while loading, the window is trimmed a second at a time (memory), before a received frame
    # is matched to the nanosecond (the verdict)
    lag = slack + (window_ns or 0) + LOAD_TRIM_NS

    def load(until: int) -> None:
        nonlocal nxt, rank
        while nxt is not None and nxt.t_ns <= until:
            if window_ns is not None and nxt.t_ns - lag > horizon:
                advance(nxt.t_ns - slack)
            k = _key(nxt.frame)
            copies = waiting.get(k)
            if copies is None:
                copies = waiting[k] = _Copies(k)
            copies.add(nxt, rank)
            window.append(copies)
            window_t.append(nxt.t_ns)
            rank += 1
            nxt = next(sent_it, None)

    values = latency.values

    def settle(s: Observed, r: Observed, s_rank: int) -> None:
        """r is the copy s (s_rank: its place in the sent stream): counted, in arrival order."""
        nonlocal previous, previous_seq, stamp_count, stamp_max_ns, seq_count
        counts["matched"] += 1
        if keep_matched:
            c.matched.append((s, r))
        if on_match is not None:
            on_match(s, r)
        # reordering: received order against sent order, globally and per id
        if previous is not None and s.index < previous.index:
            _note(c, c.reordered, (s, previous), "reordered", keep)
        ident = (s.frame.can_id, s.frame.extended)
        last = last_by_id.get(ident, -1)
        if s.index < last:
            c.reordered_per_id += 1
        else:
            last_by_id[ident] = s.index
        if previous is None or s.index > previous.index:
            previous = s
        late_ns = r.t_ns - s.t_ns
        if len(values) < latency.cap:  # Distribution.add's exact mode, inline: the hot path
            values.append(late_ns / 1e6)
        else:
            latency.add(late_ns / 1e6)
        if cuts:  # the recent latency range, for an outage's doubt
            if late_ns > recent[1]:
                recent[1] = late_ns
            recent[2] += 1
            if recent[2] == RECENT:
                recent[0], recent[1], recent[2] = recent[1], 0, 0
        if r.t_ns < s.t_ns:
            _note(c, c.negative, (s, r), "negative", keep)
        if windows:
            faults.matched(s, r, c, keep)
        if attachment:
            # the bridge's own account against the oracle's (reported, never used to judge):
            # its stamp of the frame (at the capture's microseconds), and its numbering of two
            # frames that arrived one after the other against their distance on the bus
            if r.bridge_rx_ns and r.bridge_rx_ns // 1000 != s.t_ns // 1000:
                stamp_count += 1
                stamp_max_ns = max(stamp_max_ns, abs(r.bridge_rx_ns - s.t_ns))
                if len(stamps) < EXAMPLES:
                    stamps.append(f"{describe(s)}: bridge stamp {(r.bridge_rx_ns - s.t_ns) / 1000:+.3f} us off")
            if r.seq >= 0:
                if previous_seq is not None:
                    s0, r0, rank0 = previous_seq
                    if r.seq - r0.seq != s_rank - rank0:
                        seq_count += 1
                        if len(seqs) < EXAMPLES:
                            seqs.append(f"seq {r0.seq} -> {r.seq} for {describe(s0)} -> {describe(s)} "
                                        f"({s_rank - rank0:+d} on the bus)")
                previous_seq = (s, r, s_rank)

    doubt: _Doubt | None = None
    recent = [0, 0, 0]  # the highest latency (ns) of the last block of RECENT matches, of this one, matches in it
    doubts = explained is None  # Zenoh -> CAN and round trips keep the greedy match alone
    late_only: Counter = Counter()  # a fault's settling -> its doubts with no later copy the greedy match kept
    rematched = 0  # frames matched again for doubts so far (REMATCH_SHARE)
    todo: deque[Observed] = deque()  # received frames to match again, once a doubt is resolved

    def unmatched(r: Observed, k: tuple) -> tuple[int, Observed, Observed | None, int]:
        """r matched no copy: an ECU's frame (explained), a duplicate, or, once the window tells, a
        corruption or an unexpected frame (leftovers)."""
        if explained is not None and explained[k] > 0:
            explained[k] -= 1
            c.received -= 1
            return _THEIRS, r, None, 0
        # a copy sent by the time it arrived: a frame matched again after a doubt must not see the
        # copies loaded since (a corrupted counter read as a later value's duplicate, that frame lost)
        copies = waiting.get(k)
        if copies is not None and copies.times[copies.start] <= r.t_ns + slack:
            return _DUPLICATE, r, None, 0
        return _LEFT, r, None, frontier

    def step(r: Observed, may_doubt: bool) -> tuple[int, Observed, Observed | None, int]:
        """The greedy match of r, marked: (kind, r, copy, its rank or the frontier); a doubt noted."""
        nonlocal frontier, doubt
        if nxt is not None and nxt.t_ns <= r.t_ns + slack:
            load(r.t_ns + slack)
        if window_ns is not None and r.t_ns - window_ns > horizon:
            advance(r.t_ns)
        k = _key(r.frame)
        copies = waiting.get(k)
        if copies is None:
            return unmatched(r, k)
        if doubt is not None and id(copies) not in doubt.arrived:
            doubt.arrived[id(copies)] = (copies, copies.arrived)
        at = copies.take(frontier, r.t_ns, may_doubt)
        if at is None:
            return unmatched(r, k)
        if at < 0:
            at = ~at
            if doubt is None:
                doubt = _Doubt(r, copies, at, frontier)
            else:
                doubt.inner = True
        elif cuts and may_doubt and doubt is None and recent[0] and copies.indices[at] > frontier and \
                (outage := _outage_copy(copies, at, r.t_ns, max(recent[0], recent[1]), cuts)) is not None and \
                (outage[0] is not None or late_only.get(outage[1], 0) < LATE_ONLY_DOUBTS):
            doubt = _Doubt(r, copies, at, frontier)
            doubt.late, settled = outage
            doubt.outage = True
            doubt.ended = settled - FAULT_SETTLE_NS
            doubt.recent = max(recent[0], recent[1])
            doubt.cycle = _cycle(copies.times, at)
            # held for OUTAGE_HOLD cycles at least (backlogs released one after the other, overlapping
            # stalls, break the outage's story only with the second one), and until the fault settled:
            # a burst of jitter or a queue while the link comes back, worked off by then, is no outage
            doubt.until = max(r.t_ns + OUTAGE_HOLD * doubt.cycle, settled)
        s = copies.frames[at]
        assert s is not None
        if s.index > frontier:
            frontier = s.index
        if doubt is not None:
            doubt.marks.append((copies, s.index))
            doubt.marked.add(s.index)
            doubt.oldest = min(doubt.oldest, s.t_ns)
        return _MATCHED, r, s, copies.ranks[at]

    def emit(kind: int, r: Observed, s: Observed | None, n: int) -> None:
        if kind == _MATCHED:
            settle(s, r, n)  # type: ignore[arg-type]
        elif kind == _DUPLICATE:
            _note(c, c.duplicates, r, "duplicates", keep)
        elif kind == _THEIRS:
            others.append(r)
        else:
            leftovers.append((r, n))

    def begin_story(d: _Doubt) -> tuple[int, tuple]:
        """Another story than the greedy one is to be matched on the doubt's frames: its cost
        counted (REMATCH_SHARE), the greedy story kept (greedy_again), every mark since the doubt
        undone, the frontier back to the doubt's. The index of the frame before the doubt's, and the
        greedy story."""
        nonlocal frontier, rematched
        rematched += len(d.queue)
        greedy = d.marks, frontier, [(copies, copies.arrived) for copies, _ in d.arrived.values()]
        d.undo()
        frontier = d.frontier
        return (previous.index if previous is not None else -1), greedy

    def greedy_again(d: _Doubt, greedy: tuple) -> None:
        """The greedy story back after another was matched: its marks, frontier and paces."""
        nonlocal frontier
        d.undo()
        d.marks, frontier, arrived = greedy
        for copies, index in d.marks:
            copies.mark(index, True)
        for copies, value in arrived:
            copies.arrived = value

    def duplicate_story(d: _Doubt) -> bool:
        """Matches the frames after the doubtful one again as if it were a duplicate, and tells if
        that story is the better one: fewer faults than the greedy story, and no copy left behind
        that the greedy story matched (a late frame the greedy match read as a later copy would
        become a duplicate and a loss). If so its marks stay, else the greedy story's are back."""
        nonlocal frontier
        top, greedy = begin_story(d)
        story = [unmatched(d.frame, d.copies.key)] + [step(r, False) for _, r, _, _ in d.queue[1:]]
        matched = {index for _, index in d.marks}
        # nor a copy of its own content before the one it took left unmatched in the window: the
        # frame may be that copy, late (delayed past its next copy in a batch, the greedy match then
        # one copy on until the end), not a duplicate and a loss
        if _faults(story, top) < _faults(d.queue, top) and \
                d.copies.free_between(-1, d.index, d.frame.t_ns, set()) is None and \
                all(index in matched or index > frontier for _, index in greedy[0]):
            return True
        greedy_again(d, greedy)
        return False

    def outage_story(d: _Doubt) -> bool:
        """Matches the frames after the doubtful one again as if it were the later copy (d.late,
        the ones between lost), and tells if that story is the better one: no more faults than the
        greedy story. If so its marks stay, else the greedy story's are back."""
        nonlocal frontier
        assert d.late is not None
        top, greedy = begin_story(d)
        frontier = max(d.frontier, d.late)
        d.copies.mark(d.late, True)
        d.marks.append((d.copies, d.late))
        d.copies.arrived = d.frame.t_ns
        at = d.copies.at(d.late)
        story = [(_MATCHED, d.frame, d.copies.frames[at], d.copies.ranks[at])] + \
            [step(r, False) for _, r, _, _ in d.queue[1:]]
        if _faults(story, top) <= _faults(d.queue, top):
            return True
        greedy_again(d, greedy)
        return False

    def backlog_end(d: _Doubt) -> tuple[int, _Copies, int] | None:
        """Where the live frames start after a backlog, when the link's queue overflowed during the
        fault: (the queue's frame, the copy it is instead of the one the greedy match took). The last
        frame is the copy of its content at the latency before the fault (d.recent); from there back,
        received frames and sent copies are aligned one for one (the link keeps order and, once its
        queue drains, loses nothing) down to the first copy sent after the backlog's first frame
        arrived, less that latency (the queue drains from then on, what was sent before and did not
        fit is lost). None: no such place, or the greedy match's."""
        if d.bounded:
            return None  # weighed at the bound, perhaps mid-backlog: its end not seen
        kind, r, s, _ = d.queue[-1]
        if kind != _MATCHED:
            return None
        assert s is not None
        copies = waiting.get(_key(r.frame))
        if copies is None:
            return None
        at = copies.at(s.index)
        times = copies.times
        cycle = _cycle(times, at) if at + 1 < len(times) else times[at] - times[at - 1] if at > copies.start else 0
        live = bisect.bisect_left(times, r.t_ns - d.recent - cycle // 2, at)
        if live >= len(times) or times[live] > r.t_ns or (live != at and copies.used[live]):
            return None
        first = rank - len(window)  # the rank of window[0]
        q, rk = len(d.queue) - 1, copies.ranks[live]
        since = d.frame.t_ns - d.recent
        while q > 1 and rk > first:
            r2 = d.queue[q - 1][1]
            back = rk - 1 - first - len(window)  # from the right end, nearer: a deque walks from there
            if window[back].key != _key(r2.frame) or not since <= window_t[back] <= r2.t_ns + slack:
                break
            q, rk = q - 1, rk - 1
        jump = rk - first - len(window)  # the jumped copy's place in the window, from its right end
        if q <= 1 or rk <= first or window_t[jump - 1] >= d.ended:
            # paired back to the doubtful frame: no backlog's end found (nothing lost, a latency that
            # rose pairs so on periodic contents); or the copies it skips were sent after the fault
            return None
        kind, r, s, s_rank = d.queue[q]
        if kind == _MATCHED and s_rank == rk:
            return None  # the greedy match already reads it so
        before = d.queue[q - 1]
        if window_t[jump - 1] > before[1].t_ns:
            return None  # a copy it skips sent after the backlog's last frame arrived: the queue had room
        # the backlog's last frame came at the backlog's pace, and so did the jumped one if its copy
        # was sent before that frame came: a queue drains its frames one after the other, never
        # idle while it holds one (a live frame taken for the backlog's last, or the jump taken a
        # copy early, by a frame published twice among the first live ones)
        if q >= 3:
            gap = 2 * (d.queue[q - 2][1].t_ns - d.frame.t_ns) // (q - 2) + max(QUEUED_NS, d.recent)
            if before[1].t_ns - d.queue[q - 2][1].t_ns > gap or \
                    (window_t[jump] < before[1].t_ns - d.recent and
                     d.queue[q][1].t_ns - before[1].t_ns > gap):
                return None
        # the backlog: the first copies sent in the fault, kept in order (a FIFO that drops what does
        # not fit), so matched to copies one after the other; else not this story (a frame published
        # twice at the backlog's end: its first took a lost copy of its content)
        if any(entry[0] != _MATCHED for entry in d.queue[:q]) or \
                any(d.queue[i + 1][3] != d.queue[i][3] + 1 for i in range(q - 1)):
            return None
        # two frames of one content next to each other in it, the second much faster than the backlog
        # comes: published twice (the story would take a lost copy for it, hiding the duplicate)
        pace = (d.queue[q - 1][1].t_ns - d.frame.t_ns) // max(1, q - 1)
        if any(_key(d.queue[i][1].frame) == _key(d.queue[i + 1][1].frame) and
               DUPLICATE_PACE * (d.queue[i + 1][1].t_ns - d.queue[i][1].t_ns) < pace for i in range(q - 1)):
            return None
        jumped = window[jump]
        if window[jump - 1] is jumped:
            # the copy before the jumped one is of the same content: a story jumping one copy earlier
            # pairs as well, and a frame published twice among the first live ones would shift it so,
            # unseen (the duplicate taken for a copy lost in the stall): the contents cannot tell
            return None
        where = bisect.bisect_left(jumped.ranks, rk, jumped.start)
        if _key(before[1].frame) == jumped.key and where + 1 < len(jumped.times) and \
                DUPLICATE_PACE * (r.t_ns - before[1].t_ns) < _cycle(jumped.times, where):
            return None  # the frame before it is its content at a duplicate's pace
        if len(d.queue) - q < BACKLOG_LIVE:
            return None  # no live frame after the jump: the backlog's end not seen
        if queued_at_pace(d, q, jump) or still_draining(d, q, jump):
            return None
        # the backlog came faster than it was sent (a burst, or a queue drained): not a latency that
        # rose and stays, whose frames come at their pace and align as well on periodic contents
        last = next((entry for entry in reversed(d.queue[:q]) if entry[0] == _MATCHED), None)
        s_first, s_last = d.queue[0][2], last[2] if last else None
        if last is None or s_first is None or s_last is None or \
                BACKLOG_PACE * (last[1].t_ns - d.frame.t_ns) > s_last.t_ns - s_first.t_ns:
            return None
        return q, jumped, jumped.indices[where]

    def queued_at_pace(d: _Doubt, q: int, back: int) -> bool:
        """The live frames from d.queue[q] on, paired one for one with the sent copies from window
        position back (from the right), hold a stretch of queued frames (later than the latency
        before the fault by more than half the gap to the next copy, and by QUEUED_NS) that came at
        about the pace they were sent: a FIFO queue draining delivers faster than that (BACKLOG_PACE,
        as the backlog). Such a plateau is the pairing shifted by a frame published twice among
        identical ones, each frame before it paired with the copy before its own (the story would
        take a lost copy for the duplicate)."""
        stretch: list[tuple[int, int]] = []  # (arrival, sent) of the stretch's first and last queued frames
        for k in range(len(d.queue) - q + 1):
            if k < len(d.queue) - q and back + k + 1 < 0:
                arrival, sent = d.queue[q + k][1].t_ns, window_t[back + k]
                if arrival - sent - d.recent > max(QUEUED_NS, (window_t[back + k + 1] - sent) // 2):
                    stretch[1:] = [(arrival, sent)] if stretch else [(arrival, sent), (arrival, sent)]
                    continue
            if stretch and BACKLOG_PACE * (stretch[1][0] - stretch[0][0]) > stretch[1][1] - stretch[0][1] + QUEUED_NS:
                return True
            stretch = []
        return False

    def still_draining(d: _Doubt, q: int, back: int) -> bool:
        """The last LIVE_TAIL frames (of those from d.queue[q] on, paired one for one with the sent
        copies from window position back) came faster than those copies were sent: a backlog still
        draining when the doubt was weighed, its last frame taken for a live one at the latency
        before the fault (on repeating contents a recent copy of it is always there), not the
        backlog's end."""
        k = max(0, len(d.queue) - q - LIVE_TAIL)
        last = len(d.queue) - q - 1
        if last - k < 1:
            return False
        arrived = d.queue[q + last][1].t_ns - d.queue[q + k][1].t_ns
        return BACKLOG_PACE * arrived < window_t[back + last] - window_t[back + k]

    def overflow_story(d: _Doubt, at: int, jumped: _Copies, index: int) -> bool:
        """Matches the frames from d.queue[at] again as if it were the copy at bus position index
        (a queue that overflowed: backlog_end), the frames before it as the greedy match read them,
        and tells if that story is the one: no fault at all (the link keeps order, the queue kept its
        first frames: nothing reordered, nothing twice). If so its marks stay, else the greedy story's
        are back."""
        nonlocal frontier
        top, greedy = begin_story(d)
        before = sum(1 for entry in d.queue[:at] if entry[0] == _MATCHED)
        d.marks = greedy[0][:before]
        for copies, i in d.marks:
            copies.mark(i, True)
            frontier = max(frontier, i)
        for kind, r, _, _ in d.queue[:at]:
            if kind == _MATCHED:
                waiting[_key(r.frame)].arrived = r.t_ns
        where = jumped.at(index)
        r = d.queue[at][1]
        if jumped.used[where]:
            greedy_again(d, greedy)
            return False
        jumped.mark(index, True)
        d.marks.append((jumped, index))
        frontier = max(frontier, index)
        jumped.arrived = r.t_ns
        story = d.queue[:at] + [(_MATCHED, r, jumped.frames[where], jumped.ranks[where])] + \
            [step(r2, False) for _, r2, _, _ in d.queue[at + 1:]]
        if _faults(story, top) == 0:  # in order, nothing twice (the link keeps order): else not this story
            return True
        greedy_again(d, greedy)
        return False

    def resolve() -> None:
        """The doubtful frame is the copy it took (the greedy match), or a duplicate if suspect and
        that story is the better one (an outage's doubt: the later copy, or the greedy match up to
        the backlog's end and a later copy there). If a frame since was doubtful too, or the story changed,
        every change since is undone and the frames after it are matched again."""
        nonlocal doubt, frontier, doubts, rematched
        d = doubt
        assert d is not None
        duplicate = d.suspect and not d.outage and duplicate_story(d)
        outage = d.suspect and d.late is not None and outage_story(d)
        overflow = None
        if d.suspect and d.outage and not outage:
            end = backlog_end(d)
            if end is not None and overflow_story(d, *end):
                overflow = end
        doubt = None
        if doubts and rematched > REMATCH_SHARE * c.received + REMATCH_FLOOR:
            doubts = False  # the budget spent: no new doubt, the run's rest matched greedily (said in counts)
            counts["doubts_budget_spent_at"] = c.received
        # the greedy match stands, its verdicts as they were; not an outage's doubt opened with no later copy
        # (a frame merely late around a cut): its frames matched again, another doubt may open among them
        if d.outage and d.late is None and not overflow:
            late_only[d.ended + FAULT_SETTLE_NS] += 1
        if not duplicate and not outage and not overflow and not d.inner and not (d.outage and d.late is None):
            for entry in d.queue:
                emit(*entry)
            return
        kept = iter(d.marks)  # the story taken: the greedy match's marks up to the backlog's end first
        d.undo()
        frontier = d.frontier
        if duplicate:
            emit(*unmatched(d.frame, d.copies.key))
        elif outage:
            assert d.late is not None
            d.copies.mark(d.late, True)
            d.copies.arrived = d.frame.t_ns
            at = d.copies.at(d.late)
            s_late = d.copies.frames[at]
            assert s_late is not None
            frontier = max(frontier, d.late)
            settle(s_late, d.frame, d.copies.ranks[at])
        elif overflow:
            j, jumped, index = overflow
            for entry in d.queue[:j]:  # the greedy match's verdicts up to the backlog's end
                if entry[0] == _MATCHED:
                    copies, i = next(kept)
                    copies.mark(i, True)
                    copies.arrived = entry[1].t_ns
                    frontier = max(frontier, i)
                emit(*entry)
            at = jumped.at(index)
            s_live = jumped.frames[at]
            assert s_live is not None
            jumped.mark(index, True)
            jumped.arrived = d.queue[j][1].t_ns
            frontier = max(frontier, index)
            settle(s_live, d.queue[j][1], jumped.ranks[at])
        else:
            _, r, s, s_rank = d.queue[0]
            assert s is not None
            d.copies.mark(s.index, True)
            frontier = max(frontier, s.index)
            settle(s, r, s_rank)
        rematched += len(d.queue)
        todo.extendleft(r for _, r, _, _ in reversed(d.queue[overflow[0] + 1 if overflow else 1:]))

    def weigh_outage(d: _Doubt) -> None:
        """An outage's doubt decided: the outage's story against the greedy one on the frames since
        (a backlog worked off, a burst of jitter: the outage's story then takes the copies it skipped
        behind the frontier, faults the greedy one does not have; a real outage: the greedy match
        stays shifted, its latency the gap's, with faults where it meets frames of other contents)."""
        d.suspect = True
        resolve()

    def match(r: Observed) -> None:
        """Matches r; while a doubt is open, its verdict is held back with the doubt's."""
        if doubt is not None and window_ns is not None and doubt.oldest < r.t_ns - window_ns:
            todo.appendleft(r)
            # before a copy it marked leaves the window (an outage's doubt weighed: a cut of ~20 s)
            if doubt.outage:
                doubt.bounded = True  # weighed before its live traffic came: no backlog's end (backlog_end)
                weigh_outage(doubt)
            else:
                resolve()
            return
        if doubt is None:
            entry = step(r, doubts)
            if doubt is not None:
                doubt.queue.append(entry)
            elif entry[0] == _MATCHED:
                settle(entry[2], r, entry[3])  # type: ignore[arg-type]
            else:
                emit(*entry)
            return
        k = _key(r.frame)
        again = k == doubt.copies.key
        if doubt.outage:
            pace = doubt.copies.arrived  # its arrival (the content's last)
            entry = step(r, doubts)  # a frame doubtful as a duplicate meanwhile: all matched again after
            doubt.queue.append(entry)
            if len(doubt.queue) >= DOUBT_FRAMES:
                doubt.bounded = True  # perhaps mid-backlog: no backlog's end (backlog_end)
                weigh_outage(doubt)  # a busy bus: weighed on what the bound let it see
            elif again and pace is not None and DUPLICATE_PACE * (r.t_ns - pace) >= doubt.cycle and \
                    r.t_ns >= doubt.until:
                # its content again at its own pace (not in the burst of a backlog or of a batch), the
                # fault settled: both stories weighed on everything since
                weigh_outage(doubt)
            elif doubt.late is None and r.t_ns >= doubt.until + doubt.cycle:
                # only a backlog's end may tell, and its content did not come again a cycle after the
                # fault settled (a signal that changed): weighed now, not held to the bound
                weigh_outage(doubt)
            return
        passed = False
        if again and not doubt.suspect:
            # its content again before the stream passed the copy the doubtful frame took: after
            # frames sent before that copy, this may be that copy
            if doubt.reach == doubt.frontier:
                todo.appendleft(r)
                resolve()
                return
            doubt.suspect = True
        elif not doubt.suspect:
            copies = waiting.get(k)
            reached = copies.free_between(doubt.reach, doubt.index, r.t_ns, doubt.marked) if copies else None
            if reached is not None:
                doubt.reach = reached
            else:
                passed = True
        pace = doubt.copies.arrived  # its content's last arrival, before r's
        entry = step(r, doubts)
        doubt.queue.append(entry)
        s = entry[2]
        if len(doubt.queue) >= DOUBT_FRAMES:
            resolve()  # a bound on the verdicts held back, and on the frames matched again
        elif not doubt.suspect:
            if passed and s is not None and s.index > doubt.frontier:
                resolve()  # the stream passed its copy's place: it was that copy
        elif again and pace is not None and DUPLICATE_PACE * (r.t_ns - pace) >= doubt.cycle:
            # its content at its own pace again: a backlog is over. The greedy match's breaks (frames
            # read behind, a copy taken too far) show where each backlog ends, as long as its shift lasts
            faults = _faults(doubt.queue, previous.index if previous is not None else -1)
            if faults > doubt.faults and doubt.backlogs < DOUBT_BACKLOGS:
                doubt.faults = faults
                doubt.backlogs += 1
            else:
                resolve()

    for r in received:
        c.received += 1
        match(r)
        while todo:
            match(todo.popleft())
    while doubt is not None:
        if doubt.outage:
            weigh_outage(doubt)  # the run ended before the fault settled: weighed on what it saw
        else:
            resolve()
        while todo:
            match(todo.popleft())
    load(_END)
    advance(_END)
    c.sent = rank
    faults.finish(c, keep)
    if keep is None:
        c.lost.sort(key=lambda o: o.index)
        c.lost_in_faults.sort(key=lambda o: o.index)
    if attachment:
        c.attachment = {"can_stamp": {"count": stamp_count, "max_us": round(stamp_max_ns / 1000, 3),
                                      "examples": stamps},
                        "seq": {"count": seq_count, "examples": seqs}}
    return c, others


FAULT_LEAD_NS = 1_000_000_000  # frames this long before a fault may still be in flight (queues, TCP buffers)
# Reconnection settles after its first frame: measured in the one-hour soak, zenohd 1.10.2 and a client
# re-establishing their session lost 1 sample 3 ms after the first one got through (once in 11 restarts).
FAULT_SETTLE_NS = 1_000_000_000


def apply_fault_windows(c: Comparison, windows: list[tuple[int, int]]) -> None:
    """Loss inside a fault window is the fault's, not the bridge's: a lost frame sent between
    a fault's start (minus FAULT_LEAD_NS) and FAULT_SETTLE_NS after the first frame bridged
    after the fault's end moves from lost to lost_in_faults. recovery_s per window: fault
    end -> arrival of that first frame (None: nothing sent after the fault got through).
    On a comparison that kept its matched pairs (compare); compare_stream and compare take
    the windows and apply the same rule during the pass."""
    matched = sorted(c.matched, key=lambda p: p[0].t_ns)
    allowed = []
    for start_ns, end_ns in windows:
        first = next(((s, r) for s, r in matched if s.t_ns >= end_ns), None)
        c.recovery_s.append(round((first[1].t_ns - end_ns) / 1e9, 3) if first else None)
        allowed.append((start_ns - FAULT_LEAD_NS, first[0].t_ns + FAULT_SETTLE_NS if first else end_ns))
    moved = [o for o in c.lost if any(a <= o.t_ns < b for a, b in allowed)]
    c.lost_in_faults = sorted(c.lost_in_faults + moved, key=lambda o: o.index)
    c.lost = [o for o in c.lost if not any(a <= o.t_ns < b for a, b in allowed)]
    c.counts["lost"] -= len(moved)
    c.counts["lost_in_faults"] += len(moved)


class CycleTimes:
    """Per id: count and cycle time statistics (ms) of a stream, frame by frame; the gaps
    per id in a Distribution of CYCLE_EXACT values (then its sketch)."""

    def __init__(self) -> None:
        self.ids: dict[tuple, list] = {}  # (id, ext) -> [last stamp, gaps, first stamp]

    def add(self, o: Observed) -> None:
        f = o.frame
        seen = self.ids.get((f.can_id, f.extended))
        if seen is None:
            self.ids[(f.can_id, f.extended)] = [o.t_ns, Distribution(CYCLE_EXACT, sample=False), o.t_ns]
            return
        gaps = seen[1]
        gap = (o.t_ns - seen[0]) / 1e6
        seen[0] = o.t_ns
        if len(gaps.values) < CYCLE_EXACT:  # exact mode, inline
            gaps.values.append(gap)
        else:
            gaps.add(gap)

    def result(self) -> dict[str, dict]:
        out = {}
        for (can_id, extended), (last, gaps, first) in self.ids.items():
            stats = gaps.stats()
            out[wire.id_hex(can_id, extended)] = {"count": len(gaps) + 1, "cycle_p50_ms": stats["p50_ms"],
                                                  "cycle_min_ms": stats["min_ms"], "cycle_max_ms": stats["max_ms"],
                                                  # the gaps' spread without a tenth at each end (jitter)
                                                  "cycle_p10_ms": gaps.percentile(0.1),
                                                  "cycle_p90_ms": gaps.percentile(0.9),
                                                  # its frames' rate: the cycle of an id sent in bursts
                                                  "cycle_mean_ms": (last - first) / 1e6 / len(gaps) if len(gaps)
                                                  else None}
        return dict(sorted(out.items()))


CYCLE_EXACT = 1 << 13  # gaps kept exactly per id (64 KiB), then the sketch (canbench.distribution)


def cycle_times(frames: Iterable[Observed]) -> dict[str, dict]:
    """Per id: count and cycle time statistics (ms) of a CAN stream."""
    acc = CycleTimes()
    for o in frames:
        acc.add(o)
    return acc.result()


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
