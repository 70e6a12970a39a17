"""A ground-truth proof of the oracle: traffic with heavy repetition (constant frames,
identical bursts, wrapping counters, ids sharing a payload, several buses) goes through a
simulated faulty bridge with faults at known places (canbench.groundtruth); both captures
are written in their real formats with the true stamps and read back through the bench's
own codecs; the oracle's counts, the frames it names, and every latency must be the truth.
Bounded: derandomized (fixed examples, same every run), max_examples below, < 60 s."""
from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbench import groundtruth, oracle
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
