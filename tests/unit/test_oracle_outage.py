"""Outages against the oracle's look-ahead (docs/bench.md, "The oracle"): seeded bus traffic of
several ids (constant frames, counters, contents drawn from a few values), everything sent for a
while lost, the rest delivered with known latencies, and sometimes reordering and duplicates
elsewhere. The frames after the gap must take their own copies, not the lost ones in it: the
lost frames, the reordering and every latency are the truth. And the look-ahead must not read a
backlog delivered late as an outage."""
from __future__ import annotations

import random

import pytest

from canbench import groundtruth, wire
from canbench.oracle import LOOKAHEAD, Observed, compare, compare_stream

pytestmark = pytest.mark.unit

T0, MS = 1_700_000_000_000_000_000, 1_000_000
LATENCY_NS = 300_000
# (id, cycle ms, contents): constant, a counter wrapping at 4, or one of three values at random
IDS = ((0x0C0, 10, "constant"), (0x0F0, 5, "constant"), (0x1A0, 20, "counter"), (0x2B0, 10, "few"),
       (0x3C0, 50, "few"), (0x4D0, 25, "counter"))


def bus(rng: random.Random, seconds: float, ids=IDS) -> list[Observed]:
    events = []
    for can_id, cycle_ms, contents in ids:
        phase = rng.randrange(cycle_ms * 1000) * 1000
        for k in range(int(seconds * 1000) // cycle_ms):
            data = (bytes([can_id & 0xFF, 0x10]) if contents == "constant" else
                    bytes([k % 4, 0]) if contents == "counter" else bytes([rng.randrange(3), 0]))
            events.append((T0 + k * cycle_ms * MS + phase, can_id, data))
    events.sort()
    return [Observed(wire.Frame(can_id, 2, data), t, i, line=i + 1) for i, (t, can_id, data) in enumerate(events)]


class Truth:
    """What a bridge delivered (in arrival order) and the answer the oracle must give."""

    def __init__(self, sent: list[Observed]) -> None:
        self.sent = sent
        self.received: list[Observed] = []
        self.lost: list[int] = []
        self.duplicates: list[int] = []  # positions in the received stream
        self.reordered: list[tuple[int, int]] = []
        self.latency_ms: dict[int, float] = {}


def deliver(sent: list[Observed], rng: random.Random, lost: set[int], *, swaps: tuple[int, ...] = (),
            dups: tuple[int, ...] = (), max_batch: int = 1) -> Truth:
    """Every frame not in `lost` delivered LATENCY_NS (+ jitter) after it was sent, in samples of
    1..max_batch frames (received after the last of them was sent); the frames at `swaps` change
    places with the next one delivered, those at `dups` are delivered twice."""
    truth = Truth(sent)
    order = [s for s in sent if s.index not in lost]
    for i in swaps:
        at = next(p for p, s in enumerate(order) if s.index == i)
        order[at], order[at + 1] = order[at + 1], order[at]
        truth.reordered.append((order[at + 1].index, order[at].index))
    items = []
    for s in order:
        items.append(s)
        if s.index in dups:
            items.append(s)
    last = 0
    at = 0
    arrival: dict[int, int] = {}
    while at < len(items):
        # a sample does not reach across a gap (a frame held back with the frames after an outage
        # reads as a loss when a copy of it was sent meanwhile: nothing can tell them apart)
        end = at + 1
        for _ in range(rng.randint(1, max_batch) - 1):
            if end == len(items) or abs(items[end].index - items[end - 1].index) > 1:
                break
            end += 1
        batch = items[at:end]
        last = max(last + 1000, max(s.t_ns for s in batch) + LATENCY_NS + rng.randrange(40_000))
        for s in batch:
            if s.index in arrival:
                truth.duplicates.append(len(truth.received))
            else:
                arrival[s.index] = last
            truth.received.append(Observed(s.frame, last, len(truth.received), key="vehicle/can/rx"))
        at = end
    # copies of a run of identical back-to-back frames are told apart by nobody: the lost ones are
    # named the run's last (docs/bench.md, "What the oracle can tell"), the delivered ones its first
    runs = groundtruth.identical_runs([(s.t_ns, s.frame) for s in sent])
    for start in {runs[i] for i in lost}:
        members = [i for i in range(start, len(sent)) if runs[i] == start]
        got = sorted(arrival.pop(i) for i in members if i not in lost)
        arrival.update(zip(members, got, strict=False))
        lost = (lost - set(members)) | set(members[len(got):])
    truth.latency_ms = {i: (t - sent[i].t_ns) / 1e6 for i, t in arrival.items()}
    truth.lost = sorted(lost)
    return truth


def outage(sent: list[Observed], start_ns: int, end_ns: int) -> set[int]:
    return {s.index for s in sent if start_ns <= s.t_ns < end_ns}


def assert_truth(truth: Truth) -> None:
    whole = compare(truth.sent, truth.received)
    streamed = compare_stream(iter(truth.sent), iter(truth.received), keep=100_000)
    for c in (whole, streamed):
        assert [o.index for o in c.lost] == truth.lost
        assert [r.index for r in c.duplicates] == truth.duplicates
        assert [(a.index, b.index) for a, b in c.reordered] == truth.reordered
        assert not c.corrupted and not c.unexpected and not c.negative
    assert {s.index: (r.t_ns - s.t_ns) / 1e6 for s, r in whole.matched} == truth.latency_ms
    assert list(streamed.latency_ms) == list(whole.latency_ms)


@pytest.mark.parametrize("seed", range(6))
def test_an_outage_on_traffic_of_varied_contents(seed):
    rng = random.Random(seed)
    sent = bus(rng, 3)
    start = T0 + rng.randrange(800, 1600) * MS
    truth = deliver(sent, rng, outage(sent, start, start + rng.randrange(50, 700) * MS))
    assert_truth(truth)


@pytest.mark.parametrize("seed", range(4))
def test_an_outage_in_samples_of_several_frames(seed):
    rng = random.Random(100 + seed)
    sent = bus(rng, 2)
    start = T0 + rng.randrange(500, 1000) * MS
    truth = deliver(sent, rng, outage(sent, start, start + rng.randrange(100, 500) * MS), max_batch=8)
    assert_truth(truth)


@pytest.mark.parametrize("seed", range(3))
def test_outages_on_several_constant_ids(seed):
    # three constant frames of their own cycles; two outages, of different lengths
    rng = random.Random(200 + seed)
    sent = bus(rng, 3, ((0x100, 10, "constant"), (0x101, 20, "constant"), (0x102, 7, "constant")))
    lost = outage(sent, T0 + 600 * MS, T0 + 900 * MS) | outage(sent, T0 + 1700 * MS, T0 + 2400 * MS)
    assert_truth(deliver(sent, rng, lost))


@pytest.mark.parametrize("where", ["start", "end"])
def test_an_outage_at_the_start_or_just_before_the_end_of_the_run(where):
    # at the end, fewer frames follow the gap than the look-ahead holds
    rng = random.Random(7)
    sent = bus(rng, 2)
    lost = outage(sent, T0, T0 + 400 * MS) if where == "start" else outage(sent, T0 + 1600 * MS, T0 + 1975 * MS)
    if where == "end":
        assert 0 < len([s for s in sent if s.index > max(lost)]) < LOOKAHEAD
    assert_truth(deliver(sent, rng, lost))


@pytest.mark.parametrize("seed", range(4))
def test_an_outage_with_reordering_and_duplicates_elsewhere(seed):
    rng = random.Random(300 + seed)
    sent = bus(rng, 3)
    start = T0 + 1000 * MS
    lost = outage(sent, start, start + 300 * MS)
    # a swap of two frames of different ids just before the gap and just after it, a duplicate of a
    # 10 ms frame before it (where nothing identical is sent before the frame arrives; after the
    # gap, a duplicate of a frame with a lost copy reads as that copy, late: docs/bench.md)
    before = max(s.index for s in sent if s.t_ns < start - 50 * MS)
    after = min(s.index for s in sent if s.t_ns > start + 300 * MS + 20 * MS)
    swaps = tuple(i for i in (before, after) if sent[i].frame.can_id not in (0x0F0, sent[i + 1].frame.can_id))
    dup = next(s.index for s in reversed(sent[:before - 5]) if s.frame.can_id == 0x0C0)
    truth = deliver(sent, rng, lost, swaps=swaps, dups=(dup,))
    assert truth.reordered and truth.duplicates
    assert_truth(truth)


def test_a_backlog_delivered_late_is_not_an_outage():
    # what the greedy rule always got right and least latency alone would not: the link stalls for
    # 400 ms and then delivers everything it held at once (~120 frames, more than the look-ahead):
    # nothing is lost, and the first frames of the burst are the oldest copies, not the newest
    rng = random.Random(11)
    sent = bus(rng, 2)
    stall, resume = T0 + 800 * MS, T0 + 1200 * MS
    held = [s for s in sent if stall <= s.t_ns < resume]
    assert len(held) > LOOKAHEAD
    truth = deliver(sent, rng, set())
    burst = {s.index: resume + LATENCY_NS + k * 2000 for k, s in enumerate(held)}
    truth.received = [Observed(r.frame, burst.get(i, r.t_ns), r.index, key=r.key)
                      for i, r in enumerate(truth.received)]
    truth.received.sort(key=lambda r: r.t_ns)
    truth.latency_ms.update({i: (t - sent[i].t_ns) / 1e6 for i, t in burst.items()})
    assert_truth(truth)
