"""Synthetic bridge traffic with a known truth: what the bus carried, what a (faulty) bridge
delivered and when, written as the two captures (can.log, zenoh.tsv) exactly as candump and
zn-capture write them, with the answer the oracle must give. Used to prove the oracle
(tests/unit/test_oracle_proof.py) and to measure it at scale (bench/oracle_scale.py).

Traffic repeats itself as real buses do: a constant status frame, a wrapping counter, two ids
with the same payload, bursts of identical frames back to back, a few frames of their own.
Faults at known places: drop, dup, swap (neighbours), delay (past k frames), corrupt (one
byte), wrongkey (published on another key); the bridge's batches put several frames in one
sample. Faults are placed where the captures can tell them (docs/bench.md, "What the oracle
can tell"): a fault's frame has no identical copy sent between it and its arrival (+ the
oracle's stamp slack), and only drops fall inside runs of identical frames, whose copies
nothing tells apart (the truth then names the run's last copies, as the oracle does)."""
from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import dataclass, field

from . import trace, wire
from .capture import Sample, format_sample_line
from .oracle import STAMP_SLACK_NS

FAULTS = ("drop", "dup", "swap", "delay", "corrupt", "wrongkey")
LATENCY_NS = 300_000        # the bridge's base latency
JITTER_NS = 40_000
FAULT_SPACING = 12          # sent frames between two faults of one bus


@dataclass
class Item:
    """One frame as the bridge delivers it."""
    sent: int                  # index of the bus frame it is (a duplicate: the same)
    frame: wire.Frame
    key: str
    kind: str = "ok"           # ok, dup, corrupt, wrongkey
    t_ns: int = 0              # receive time of its sample


@dataclass
class BusTruth:
    bus: str
    key: str
    sent: list[tuple[int, wire.Frame]]           # (bus stamp ns, frame) in bus order
    delivered: list[Item] = field(default_factory=list)
    faults: list[tuple[str, int]] = field(default_factory=list)   # (kind, sent index) applied
    lost: list[int] = field(default_factory=list)
    duplicates: list[int] = field(default_factory=list)          # positions in the key's frame stream
    corrupted: list[tuple[int, int, list[int]]] = field(default_factory=list)  # (sent, position, bytes)
    reordered: list[tuple[int, int]] = field(default_factory=list)  # (frame, the frame it arrived after)
    reordered_per_id: int = 0
    latency_ms: dict[int, float] = field(default_factory=dict)   # sent index -> ms


def traffic(rng: random.Random, n: int, t0_ns: int) -> list[tuple[int, wire.Frame]]:
    """n bus frames with heavy repetition, stamps at candump's microseconds."""
    out: list[tuple[int, wire.Frame]] = []
    t = t0_ns
    counter = 0
    while len(out) < n:
        pick = rng.random()
        if pick < 0.25:
            frames = [wire.Frame(0x100, 2, b"\x01\x02")]                         # constant status
        elif pick < 0.45:
            counter = (counter + 1) % 4                                          # wrapping counter
            frames = [wire.Frame(0x200, 2, bytes([counter, 0x10]))]
        elif pick < 0.6:
            frames = [wire.Frame(rng.choice((0x300, 0x301)), 3, b"\x55\x55\x55")]  # two ids, one payload
        elif pick < 0.7:
            frames = [wire.Frame(0x18FF0400, 1, b"\xAA", True)] * rng.randint(2, 5)  # identical burst
        else:
            frames = [wire.Frame(0x500 + rng.randrange(4), 2, rng.randbytes(2))]
        for i, f in enumerate(frames):
            t += (120 if i else rng.randint(150, 1500)) * 1000
            out.append((t, f))
    return out[:n]


def identical_runs(sent: list[tuple[int, wire.Frame]]) -> list[int]:
    """For each frame, the index of the first frame of its run of identical back-to-back frames."""
    start: list[int] = []
    for i, (_, f) in enumerate(sent):
        start.append(start[-1] if i and sent[i - 1][1] == f else i)
    return start


def in_run(runs: list[int], i: int) -> bool:
    return runs[i] != i or (i + 1 < len(runs) and runs[i + 1] == runs[i])


def _deliver(truth: BusTruth, rng: random.Random, faults: list[tuple[str, int, int]], wrong_key: str,
             max_batch: int) -> list[Item]:
    items = [Item(i, f, truth.key) for i, (_, f) in enumerate(truth.sent)]
    # applied from the back: faults are FAULT_SPACING apart, so frame i is still at position i
    for kind, i, arg in sorted(faults, key=lambda x: -x[1]):
        at = i
        it = items[at]
        assert it.sent == i and it.kind == "ok"
        if kind == "drop":
            del items[at]
        elif kind == "dup":
            items.insert(at + 1, Item(i, it.frame, it.key, "dup"))
        elif kind == "swap":
            items[at], items[at + 1] = items[at + 1], items[at]
        elif kind == "delay":
            items.insert(at + arg + 1, items.pop(at))
        elif kind == "corrupt":
            data = bytearray(it.frame.data)
            data[arg % len(data)] ^= 0x80
            items[at] = Item(i, wire.Frame(it.frame.can_id, it.frame.dlc, bytes(data), it.frame.extended),
                             it.key, "corrupt")
        elif kind == "wrongkey":
            items[at] = Item(i, it.frame, wrong_key, "wrongkey")
    # samples: consecutive items on one key, 1..max_batch frames, received after all of them were sent
    last = 0
    at = 0
    while at < len(items):
        size = 1
        while size < rng.randint(1, max_batch) and at + size < len(items) and items[at + size].key == items[at].key:
            size += 1
        batch = items[at:at + size]
        newest = max(truth.sent[it.sent][0] for it in batch)
        last = max(last + 1000, newest + LATENCY_NS + rng.randrange(JITTER_NS))
        for it in batch:
            it.t_ns = last
        at += size
    return items


def _observable(truth: BusTruth, runs: list[int], arrivals: dict[int, int], kind: str, i: int,
                lost: list[int]) -> bool:
    """The captures can tell this fault: no identical copy of the frame is sent between it and
    its arrival (+ STAMP_SLACK_NS), except a drop inside a run of identical frames."""
    if kind == "drop":
        return True
    frame = truth.sent[i][1]
    if in_run(runs, i):
        return False
    if kind == "corrupt" and (frame.remote or not frame.dlc):
        return False
    arrival = arrivals[i]
    for j in range(i + 1, len(truth.sent)):
        t, f = truth.sent[j]
        if t > arrival + STAMP_SLACK_NS:
            break
        if f == frame:
            return False
    if kind == "dup" and any(truth.sent[j][1] == frame for j in lost if j < i):
        return False  # a lost copy before it: the duplicate reads as that copy, late
    if kind == "swap":  # the neighbour moves too
        return i + 1 < len(truth.sent) and _observable(truth, runs, arrivals, "delay", i + 1, lost) \
            and truth.sent[i + 1][1] != frame
    return True


def _not_new(truth: BusTruth, items: list[Item]) -> set[int]:
    """Corrupted frames that read as another frame the bus carried (a duplicate and a loss)."""
    contents = {f for _, f in truth.sent}
    return {it.sent for it in items if it.kind == "corrupt" and it.frame in contents}


def _truth(truth: BusTruth, runs: list[int]) -> None:
    """The answer, from what was delivered: runs of identical frames matched first-come first-served."""
    stream = [it for it in truth.delivered if it.key == truth.key]
    arrivals: dict[int, list[int]] = {}      # run start -> positions of its delivered copies
    for pos, it in enumerate(stream):
        if it.kind == "ok":
            arrivals.setdefault(runs[it.sent], []).append(pos)
        elif it.kind == "dup":
            truth.duplicates.append(pos)
        elif it.kind == "corrupt":
            s = truth.sent[it.sent][1]
            truth.corrupted.append((it.sent, pos, [b for b in range(s.dlc) if s.data[b] != it.frame.data[b]]))
    match: dict[int, int] = {}                # sent index -> position
    for start, positions in arrivals.items():
        for k, pos in enumerate(sorted(positions)):
            match[start + k] = pos
    corrupted = {s for s, _, _ in truth.corrupted}
    truth.lost = [i for i in range(len(truth.sent)) if i not in match and i not in corrupted]
    truth.corrupted.sort(key=lambda c: c[1])
    highest = -1
    last_by_id: dict[tuple, int] = {}
    for pos, i in sorted((p, i) for i, p in match.items()):
        if i < highest:
            truth.reordered.append((i, highest))
        f = truth.sent[i][1]
        ident = (f.can_id, f.extended)
        if ident in last_by_id and i < last_by_id[ident]:
            truth.reordered_per_id += 1
        last_by_id[ident] = max(i, last_by_id.get(ident, -1))
        highest = max(highest, i)
        truth.latency_ms[i] = (stream[pos].t_ns - truth.sent[i][0]) / 1e6


T0_NS = 1_700_000_000_000_000_000


def generate(seed: int, frames_per_bus: int, buses: int = 1, faults: int = 4, max_batch: int = 1,
             kinds: tuple[str, ...] = FAULTS, t0_ns: int = T0_NS) -> list[BusTruth]:
    """Traffic on `buses` buses with up to `faults` faults each, and the truth per bus; the
    first frame stamped just after t0_ns."""
    rng = random.Random(seed)
    out = []
    for b in range(buses):
        bus = f"vcan{b}"
        key = "vehicle/can/rx" if buses == 1 else f"vehicle/can/{bus}/rx"
        truth = BusTruth(bus, key, traffic(rng, frames_per_bus, t0_ns + b * 37_000))
        runs = identical_runs(truth.sent)
        slots = list(range(2, frames_per_bus - 8, FAULT_SPACING))
        chosen = sorted(rng.sample(slots, min(faults, len(slots))))
        planned = [(rng.choice(kinds), i, rng.randint(1, 4)) for i in chosen]
        batch_seed = rng.random()
        while True:  # drop the faults the captures could not tell, until the rest all can be told
            items = _deliver(truth, random.Random(batch_seed), planned, f"vehicle/can/{bus}/wrong", max_batch)
            arrivals: dict[int, int] = {}
            for it in items:
                arrivals[it.sent] = max(arrivals.get(it.sent, 0), it.t_ns)
            lost = sorted(i for k, i, _ in planned if k in ("drop", "corrupt", "wrongkey"))
            keep = [f for f in planned if _observable(truth, runs, arrivals, f[0], f[1], lost)]
            untellable = _not_new(truth, items)
            if keep == planned and not untellable:
                break
            planned = keep if keep != planned else [f for f in planned if f[1] not in untellable]
        truth.delivered = items
        truth.faults = [(k, i) for k, i, _ in planned]
        _truth(truth, runs)
        out.append(truth)
    return out


def can_log_lines(truths: list[BusTruth]) -> Iterator[str]:
    """can.log: every bus's frames, in time order, as candump -L writes them."""
    merged = sorted((t, b, i) for b, truth in enumerate(truths) for i, (t, _) in enumerate(truth.sent))
    for t, b, i in merged:
        yield trace.format_line(t, truths[b].bus, truths[b].sent[i][1]) + "\n"


def zenoh_lines(truths: list[BusTruth], first_seq: int = 0) -> Iterator[str]:
    """zenoh.tsv: every sample in receive order as zn-capture writes it (attachment: a sequence
    number per frame from first_seq, and the true bus stamps)."""
    samples = []
    for b, truth in enumerate(truths):
        seq = first_seq
        at = 0
        items = truth.delivered
        while at < len(items):
            end = at + 1
            while end < len(items) and items[end].t_ns == items[at].t_ns and items[end].key == items[at].key:
                end += 1
            batch = items[at:end]
            payload = b"".join(wire.encode(it.frame) for it in batch)
            att = wire.encode_attachment(seq, [truth.sent[it.sent][0] for it in batch])
            samples.append((batch[0].t_ns, b, at, Sample(batch[0].t_ns, batch[0].key, payload, att)))
            seq += len(batch)
            at = end
    for *_, sample in sorted(samples, key=lambda s: s[:3]):
        yield format_sample_line(sample)
