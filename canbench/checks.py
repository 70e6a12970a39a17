"""The bench's checks on a run result. Each returns None when the scenario
does not ask for it, else a list of problems (empty = pass) that name the
frames and where they came from (can.log:line). Used by the scenario tests
(tests/scenarios) and by the seeded-fault tests that prove each check fails
for the fault it exists for."""
from __future__ import annotations

from collections.abc import Callable

from .oracle import describe
from .run import RunResult

SHOW = 10  # frames listed per problem


def _frames(items) -> str:
    listed = ", ".join(describe(i) for i in items[:SHOW])
    return listed + (f", ... ({len(items) - SHOW} more)" if len(items) > SHOW else "")


def _expect(result: RunResult, name: str, default=None):
    return result.scenario.expect.get(name, default)


def integrity(result: RunResult) -> list[str] | None:
    """Every frame on the bus reached Zenoh byte-exact, once (within the loss budget)."""
    if not _expect(result, "integrity", True):
        return None
    budget = _expect(result, "loss_budget", 0)
    problems = []
    for b in result.buses:
        c = b.comparison
        if not b.can_frames:
            problems.append(f"{b.bus}: no frames on the bus at all (did the ECUs run?)")
        if len(c.lost) > budget:
            problems.append(f"{b.bus}: {len(c.lost)} frames lost (budget {budget}): {_frames(c.lost)}")
        if c.duplicates:
            problems.append(f"{b.bus}: {len(c.duplicates)} duplicates on {b.rx_key}: {_frames(c.duplicates)}")
        if c.corrupted:
            listed = "; ".join(f"{describe(s)} arrived as {r.frame.candump().split(' ', 1)[1]} (bytes {diff})"
                               for s, r, diff in c.corrupted[:SHOW])
            problems.append(f"{b.bus}: {len(c.corrupted)} corrupted: {listed}")
        if c.unexpected:
            problems.append(f"{b.bus}: {len(c.unexpected)} frames never sent: {_frames(c.unexpected)}")
        problems += [f"{b.bus}: {p}" for p in b.problems]
    return problems


def ordering(result: RunResult) -> list[str] | None:
    """Frames arrive in bus order, globally and per id."""
    if not _expect(result, "ordering", True):
        return None
    problems = []
    for b in result.buses:
        c = b.comparison
        if c.reordered:
            listed = "; ".join(f"{describe(s)} after {describe(p)}" for s, p in c.reordered[:SHOW])
            problems.append(f"{b.bus}: {len(c.reordered)} frames out of order "
                            f"({c.reordered_per_id} within the same id): {listed}")
    return problems


def latency_can_to_zenoh(result: RunResult) -> list[str] | None:
    """Median CAN -> Zenoh latency within the scenario's gate (p99/max reported)."""
    gate = (_expect(result, "latency", {}) or {}).get("can_to_zenoh")
    if not gate:
        return None
    problems = []
    for b in result.buses:
        lat = b.comparison.summary()["latency"]
        if lat["count"] == 0:
            continue  # nothing arrived: integrity reports that, latency has nothing to measure
        if "p50_ms" in gate and lat["p50_ms"] > gate["p50_ms"]:
            problems.append(f"{b.bus}: p50 {lat['p50_ms']:.3f} ms > gate {gate['p50_ms']} ms "
                            f"(p90 {lat['p90_ms']:.3f}, p99 {lat['p99_ms']:.3f}, max {lat['max_ms']:.3f} ms)")
        if "p99_ms" in gate and lat["p99_ms"] > gate["p99_ms"]:
            problems.append(f"{b.bus}: p99 {lat['p99_ms']:.3f} ms > gate {gate['p99_ms']} ms")
    return problems


def only_expected_keys(result: RunResult) -> list[str] | None:
    """The bridge published on its own keys only."""
    return [f"samples on unexpected keys: {result.unexpected_keys}"] if result.unexpected_keys else []


def ecus_sent_their_traces(result: RunResult) -> list[str] | None:
    """Every ECU finished and the bus capture holds all it sent (the bench lost nothing)."""
    problems = [f"{e.name}: no summary" for e in result.scenario.ecus if e.name not in result.ecus]
    on_bus = sum(len(b.can_frames) for b in result.buses)
    sent = sum(s["sent"] for s in result.ecus.values())
    if on_bus < sent:
        problems.append(f"ECUs sent {sent} frames but the bus capture holds {on_bus}: the bench lost frames")
    return problems


def bridge_stats_agree(result: RunResult) -> list[str] | None:
    """The bridge's own counters agree with what the oracle saw."""
    if result.bridge_stats is None:
        return ["the bridge's stats queryable did not answer"]
    problems = []
    for b in result.buses:
        bus_stats = next((s for s in result.bridge_stats["buses"] if s["bus"] == b.bus), None)
        if bus_stats is None:
            problems.append(f"no stats for {b.bus}")
        elif bus_stats["published_frames"] != len(b.zenoh_frames):
            problems.append(f"{b.bus}: bridge says it published {bus_stats['published_frames']} frames, "
                            f"the capture received {len(b.zenoh_frames)}")
    return problems


CHECKS: dict[str, Callable[[RunResult], list[str] | None]] = {
    "integrity": integrity,
    "ordering": ordering,
    "latency_can_to_zenoh": latency_can_to_zenoh,
    "only_expected_keys": only_expected_keys,
    "ecus_sent_their_traces": ecus_sent_their_traces,
    "bridge_stats_agree": bridge_stats_agree,
}


def failing(result: RunResult) -> dict[str, list[str]]:
    """The checks that fail on this result, with their problems."""
    out = {}
    for name, check in CHECKS.items():
        problems = check(result)
        if problems:
            out[name] = problems
    return out
