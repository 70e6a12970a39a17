"""The bench's checks, one test per check, against one scenario run. Each
failure says which frames failed and where they came from (can.log:line)."""
from __future__ import annotations

import pytest

from canbench.oracle import describe

SHOW = 10  # frames listed per failure


def frames(items, key=lambda x: x) -> str:
    listed = ", ".join(describe(key(i)) for i in items[:SHOW])
    return listed + (f", ... ({len(items) - SHOW} more)" if len(items) > SHOW else "")


def expect(result, name, default=None):
    return result.scenario.expect.get(name, default)


def test_integrity(scenario_run):
    """Every frame on the bus reached Zenoh byte-exact, once (within the loss budget)."""
    if not expect(scenario_run, "integrity", True):
        pytest.skip("integrity not expected by this scenario")
    budget = expect(scenario_run, "loss_budget", 0)
    problems = []
    for b in scenario_run.buses:
        c = b.comparison
        if not b.can_frames:
            problems.append(f"{b.bus}: no frames on the bus at all (did the ECUs run?)")
        if len(c.lost) > budget:
            problems.append(f"{b.bus}: {len(c.lost)} frames lost (budget {budget}): {frames(c.lost)}")
        if c.duplicates:
            problems.append(f"{b.bus}: {len(c.duplicates)} duplicates on {b.rx_key}: {frames(c.duplicates)}")
        if c.corrupted:
            listed = "; ".join(f"{describe(s)} arrived as {r.frame.candump().split(' ', 1)[1]} "
                               f"(bytes {diff})" for s, r, diff in c.corrupted[:SHOW])
            problems.append(f"{b.bus}: {len(c.corrupted)} corrupted: {listed}")
        if c.unexpected:
            problems.append(f"{b.bus}: {len(c.unexpected)} frames never sent: {frames(c.unexpected)}")
        problems += [f"{b.bus}: {p}" for p in b.problems]
    assert not problems, "\n".join(problems)


def test_ordering(scenario_run):
    """Frames arrive in bus order, globally and per id."""
    if not expect(scenario_run, "ordering", True):
        pytest.skip("ordering not expected by this scenario")
    problems = []
    for b in scenario_run.buses:
        c = b.comparison
        if c.reordered:
            listed = "; ".join(f"{describe(s)} after {describe(p)}" for s, p in c.reordered[:SHOW])
            problems.append(f"{b.bus}: {len(c.reordered)} frames out of order "
                            f"({c.reordered_per_id} within the same id): {listed}")
    assert not problems, "\n".join(problems)


def test_latency_can_to_zenoh(scenario_run):
    """Median CAN -> Zenoh latency within the scenario's gate (p99/max reported)."""
    gate = (expect(scenario_run, "latency", {}) or {}).get("can_to_zenoh")
    if not gate:
        pytest.skip("no can_to_zenoh latency gate in this scenario")
    problems = []
    for b in scenario_run.buses:
        lat = b.comparison.summary()["latency"]
        if lat["count"] == 0:
            problems.append(f"{b.bus}: no matched frames to measure")
            continue
        if "p50_ms" in gate and lat["p50_ms"] > gate["p50_ms"]:
            problems.append(f"{b.bus}: p50 {lat['p50_ms']:.3f} ms > gate {gate['p50_ms']} ms "
                            f"(p90 {lat['p90_ms']:.3f}, p99 {lat['p99_ms']:.3f}, max {lat['max_ms']:.3f} ms)")
        if "p99_ms" in gate and lat["p99_ms"] > gate["p99_ms"]:
            problems.append(f"{b.bus}: p99 {lat['p99_ms']:.3f} ms > gate {gate['p99_ms']} ms")
    assert not problems, "\n".join(problems)


def test_only_expected_keys(scenario_run):
    """The bridge published on its own keys only."""
    assert not scenario_run.unexpected_keys, f"samples on unexpected keys: {scenario_run.unexpected_keys}"


def test_ecus_sent_their_traces(scenario_run):
    """Every ECU sent all its frames; its timing fidelity is reported in metrics.json."""
    problems = []
    for e in scenario_run.scenario.ecus:
        summary = scenario_run.ecus.get(e.name)
        if summary is None:
            problems.append(f"{e.name}: no summary")
    on_bus = sum(len(b.can_frames) for b in scenario_run.buses)
    sent = sum(s["sent"] for s in scenario_run.ecus.values())
    if on_bus < sent:
        problems.append(f"ECUs sent {sent} frames but the bus capture holds {on_bus}: the bench lost frames")
    assert not problems, "\n".join(problems)


def test_bridge_stats_agree(scenario_run):
    """The bridge's own counters agree with what the oracle saw."""
    stats = scenario_run.bridge_stats
    assert stats is not None, "the bridge's stats queryable did not answer"
    for b in scenario_run.buses:
        bus_stats = next((s for s in stats["buses"] if s["bus"] == b.bus), None)
        assert bus_stats is not None, f"no stats for {b.bus}"
        assert bus_stats["published_frames"] == len(b.zenoh_frames), (
            f"{b.bus}: bridge says it published {bus_stats['published_frames']} frames, "
            f"the capture received {len(b.zenoh_frames)}")
