"""A ground-truth proof of the oracle: traffic with heavy repetition (constant frames,
identical bursts, wrapping counters, ids sharing a payload, several buses) goes through a
simulated faulty bridge with faults at known places (canbench.groundtruth); both captures
are written in their real formats with the true stamps and read back through the bench's
own codecs; the oracle's counts, the frames it names, and every latency must be the truth.
Bounded: derandomized (fixed examples, same every run), max_examples below, < 60 s."""
from __future__ import annotations

import tempfile
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbench import groundtruth, oracle, wire
from canbench.capture import read_zenoh_capture

pytestmark = pytest.mark.unit


def analyse(truths: list[groundtruth.BusTruth], where: Path) -> dict[str, tuple[oracle.Comparison, set[str]]]:
    (where / "can.log").write_text("".join(groundtruth.can_log_lines(truths)))
    (where / "zenoh.tsv").write_text("".join(groundtruth.zenoh_lines(truths)))
    samples = read_zenoh_capture(where / "zenoh.tsv")
    keys = {s.key for s in samples}
    out = {}
    for t in truths:
        received, problems = oracle.zenoh_frames(samples, t.key)
        assert problems == []
        out[t.bus] = (oracle.compare(oracle.read_candump(where / "can.log", t.bus), received), keys)
    return out


def assert_truth(truth: groundtruth.BusTruth, c: oracle.Comparison, keys: set[str]) -> None:
    where = f"{truth.bus} faults {truth.faults}"
    assert [o.index for o in c.lost] == truth.lost, where
    assert [r.index for r in c.duplicates] == truth.duplicates, where
    assert [(s.index, r.index, diff) for s, r, diff in c.corrupted] == truth.corrupted, where
    assert c.unexpected == [], where
    assert [(a.index, b.index) for a, b in c.reordered] == truth.reordered, where
    assert c.reordered_per_id == truth.reordered_per_id, where
    assert {s.index: (r.t_ns - s.t_ns) / 1e6 for s, r in c.matched} == truth.latency_ms, where
    assert min(c.latency_ms, default=0) >= 0 and c.negative_latencies() == []
    # the attachment carries the true stamps: they agree, except where a run of identical frames lost a
    # copy (the oracle names the run's last copy; only the attachment, never trusted, knows which one)
    runs = groundtruth.identical_runs(truth.sent)
    if not any(groundtruth.in_run(runs, i) for k, i in truth.faults):
        assert c.attachment is not None and c.attachment["can_stamp"]["count"] == 0, where
    assert (f"vehicle/can/{truth.bus}/wrong" in keys) == any(k == "wrongkey" for k, _ in truth.faults)


@settings(max_examples=150, derandomize=True, database=None, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), frames=st.integers(20, 300), buses=st.integers(1, 3),
       faults=st.integers(0, 8), max_batch=st.sampled_from([1, 1, 4, 16]))
def test_oracle_finds_the_truth(seed, frames, buses, faults, max_batch):
    truths = groundtruth.generate(seed, frames, buses, faults, max_batch)
    with tempfile.TemporaryDirectory() as d:
        for truth in truths:
            c, keys = analyse(truths, Path(d))[truth.bus]
            assert_truth(truth, c, keys)


@pytest.mark.parametrize("kind", groundtruth.FAULTS)
def test_each_fault_kind_is_placed_and_found(kind):
    """Every kind of fault is exercised (not all filtered out as untellable), and found."""
    placed = 0
    for seed in range(20):
        truths = groundtruth.generate(seed, 200, 2, 6, 4, kinds=(kind,))
        placed += sum(len(t.faults) for t in truths)
        with tempfile.TemporaryDirectory() as d:
            result = analyse(truths, Path(d))
            for t in truths:
                assert_truth(t, *result[t.bus])
    assert placed >= 20


@settings(max_examples=60, derandomize=True, database=None, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), frames=st.integers(20, 200), faults=st.integers(0, 6),
       ecu_every=st.integers(2, 7))
def test_zenoh_to_can_finds_the_truth_among_the_ecus_frames(seed, frames, faults, ecu_every):
    """The same truth the other way: the generated frames are commands (put times), what the
    bridge delivered is written to the bus between frames of the ECUs (which their send logs
    explain); the commands' loss, duplicates, corruption, order and latency must be the truth,
    and exactly the ECUs' frames must be set apart as theirs."""
    truth = groundtruth.generate(seed, frames, 1, faults, 1, kinds=("drop", "dup", "swap", "delay", "corrupt"))[0]
    commands = [oracle.Observed(f, t, i, line=i + 2, origin="commands.tsv") for i, (t, f) in enumerate(truth.sent)]
    bus: list[oracle.Observed] = []
    ecu = []
    position = {}  # the delivered frame's position on the rx key -> its index on the bus
    for pos, it in enumerate(truth.delivered):
        if len(bus) % ecu_every == 0:  # an ECU's frame, stamped just before the bridge's
            f = wire.Frame(0x600 + len(ecu) % 7, 1, bytes([len(ecu) % 256]))
            ecu.append(f)
            bus.append(oracle.Observed(f, it.t_ns - 1000, len(bus), line=len(bus) + 1))
        position[pos] = len(bus)
        bus.append(oracle.Observed(it.frame, it.t_ns, len(bus), line=len(bus) + 1))
    c, theirs = oracle.compare_commands(commands, bus, Counter(oracle.frame_key(f) for f in ecu))
    assert [o.frame for o in theirs] == ecu
    assert [o.index for o in c.lost] == truth.lost
    assert [r.index for r in c.duplicates] == [position[p] for p in truth.duplicates]
    assert [(s.index, r.index, d) for s, r, d in c.corrupted] == [(s, position[p], d) for s, p, d in truth.corrupted]
    assert c.unexpected == []
    assert [(a.index, b.index) for a, b in c.reordered] == truth.reordered
    assert {s.index: (r.t_ns - s.t_ns) / 1e6 for s, r in c.matched} == truth.latency_ms
