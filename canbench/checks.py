"""The bench's checks on a run result. Each returns None when the scenario
does not ask for it, else a list of problems (empty = pass) that name the
frames and where they came from (can.log:line). Used by the scenario tests
(canbench.scenario_checks) and by the seeded-fault tests that prove each check fails
for the fault it exists for."""
from __future__ import annotations

import bisect
from collections.abc import Callable
from functools import wraps

from . import rxqos, security, signals, validity, wire
from .analysis import RunResult, bus_stats
from .capture import read_capture_stats
from .commands import explained_refusals, stale_at_put, stamp_ages_ns
from .dbc import cycle_of_id, load_dbc, send_type_at_most
from .faults import disruptive, last_bridge_restart_ns
from .oracle import FAULT_LEAD_NS, FAULT_SETTLE_NS, describe

SHOW = 10  # frames listed per problem
# The bridge judges a command's age when its transmitter takes it; the bus stamps the frame when the
# write reaches it, behind the commands taken before (a burst after a stall): that much later is allowed.
FRESHNESS_SLACK_MS = 20
# While a can_flood fault floods a bus, the emulated bus (kernel vcan, the userspace hub: first come,
# first served, one hub for every interface) takes a written command behind the flood's backlog, where
# a real bus would let a higher-priority id win arbitration at once: a command that reached any bus
# late then is the flood's (counted as late_in_floods), up to FAULT_SETTLE_NS after the flood ends.
FLOOD_ACTION = "can_flood"


def _frames(items) -> str:
    return _listed(items, describe)


def _listed(items, said) -> str:
    """The first SHOW items as said, and how many more."""
    listed = ", ".join(said(i) for i in items[:SHOW])
    return listed + (f", ... ({len(items) - SHOW} more)" if len(items) > SHOW else "")


def _expect(result: RunResult, name: str, default=None):
    return result.scenario.expect.get(name, default)


def assess(result: RunResult) -> dict:
    """Whether the run is a valid test of the bridge (canbench.validity), once per result;
    kept in metrics.json as `validity`."""
    if "validity" not in result.metrics:
        result.metrics["validity"] = validity.assess(result)
    return result.metrics["validity"]


def valid_run(result: RunResult) -> list[str] | None:
    """The bench itself worked: no impossible latency (bench error), captures that kept up,
    emulators that kept to their traces. Otherwise the run fails with that outcome and the
    bridge's checks are not judged."""
    v = assess(result)
    return [f"{outcome}: {p}" for outcome, problems in v["problems"].items() for p in problems]


# what the bench samples in its own bridge's container only (canbench.faults.Injector)
CONTAINER_SAMPLED = ("bridge_memory", "bridge_fds")


def skip_reason(result: RunResult, name: str) -> str:
    outcome = assess(result)["outcome"]
    if name != "valid_run" and outcome != "valid":
        return f"{name} not judged: the run is {outcome} (see valid_run)"
    if name in CONTAINER_SAMPLED and result.metrics.get("device"):
        return (f"{name} not judged: the bench samples its own bridge container's memory and descriptors, not "
                f"a device of your own ({result.metrics['device']})")
    if name == "bridge_stats_agree" and result.metrics.get("device_announces") is False:
        return (f"{name} not judged: the device ({result.metrics['device']}) has no stats queryable "
                f"(DEVICE_ANNOUNCES=0)")
    return f"{name} not asked for by this scenario"


def _on_the_bridge(check: Callable[[RunResult], list[str] | None]) -> Callable[[RunResult], list[str] | None]:
    """A check of the bridge: not judged (None) on a run that is not a valid test of it."""
    @wraps(check)
    def judged(result: RunResult) -> list[str] | None:
        return None if assess(result)["outcome"] != "valid" else check(result)
    return judged


def integrity(result: RunResult) -> list[str] | None:
    """Every frame the ECUs put on the bus reached Zenoh byte-exact, once (within the loss budget)."""
    if not _expect(result, "integrity", True):
        return None
    budget = _expect(result, "loss_budget", 0)
    problems = []
    for b in result.buses:
        c = b.comparison
        if not b.can_frames:
            problems.append(f"{b.bus}: no frames on the bus at all (did the ECUs run?)")
        if len(c.lost) > budget:
            problems.append(f"{b.bus}: {len(c.lost)} frames lost (budget {budget}): {_frames(c.lost)}"
                            + _numbered_by_the_bridge(result, b) + _readers_dropped(result, b.bus))
        if c.duplicates:
            problems.append(f"{b.bus}: {len(c.duplicates)} duplicates on {b.rx_key}: {_frames(c.duplicates)}")
        if c.corrupted:
            listed = "; ".join(f"{describe(s)} arrived as {r.frame.candump().split(' ', 1)[1]} (bytes {diff})"
                               for s, r, diff in c.corrupted[:SHOW])
            problems.append(f"{b.bus}: {len(c.corrupted)} corrupted: {listed}")
        if c.unexpected:
            problems.append(f"{b.bus}: {len(c.unexpected)} frames never sent: {_frames(c.unexpected)}")
        problems += [f"{b.bus}: {p}" for p in b.problems[:SHOW]]  # undecodable samples: one each, bounded
        if len(b.problems) > SHOW:
            problems.append(f"{b.bus}: ... ({len(b.problems) - SHOW} more undecodable samples, "
                            f"{len(b.problems)} in all)")
    return problems


def _numbered_by_the_bridge(result: RunResult, b) -> str:
    """Lost frames the bridge gave a sequence number (the frames that arrived either side of one, in the
    same run of the bridge, are numbered as far apart as they are on the bus): it read them, so they were
    dropped from its queue (rx_queue_drops) or lost after its put (the bridge's Zenoh session, the router,
    the capture's session), never on the bus's side. Said with its stats' drops, the evidence of which."""
    rank = {id(s): i for i, s in enumerate(b.can_frames)}
    around = sorted((rank[id(s)], r.seq) for s, r in b.comparison.matched if r.seq >= 0 and id(s) in rank)
    places = [p for p, _ in around]
    numbered = []
    for s in b.comparison.lost:
        p = rank.get(id(s))
        k = bisect.bisect(places, p) if p is not None else 0
        if 0 < k < len(around):
            (p0, q0), (p1, q1) = around[k - 1], around[k]
            if q1 - q0 == p1 - p0:
                numbered.append(f"{describe(s)} seq {q0 + p - p0}")
    if not numbered:
        return ""
    stats = bus_stats(result.bridge_stats, b.bus) if result.bridge_stats else None
    drops = (f"; its stats (its last start) count {stats.get('rx_queue_drops')} queue drops, "
             f"{stats.get('publish_errors')} frames of failed puts and {stats.get('unrouted_frames', 'no count of')} "
             f"frames put while it had no Zenoh connection" if stats else "")
    # a connection to the router that closed and came back: puts made meanwhile returned Ok and went
    # nowhere (a bridge older than the counter, or a device of your own, may not say)
    closed = (result.bridge_stats or {}).get("connections_closed")
    if stats and closed is not None:
        drops += (f", and {closed} Zenoh connections of it closed (samples put before one reopened are lost "
                  f"though their put succeeded)" if closed else ", and no Zenoh connection of it closed")
    return (f"; the bridge numbered {len(numbered)} of them ({_listed(numbered, str)}): it read them, so they were "
            f"dropped from its queue or lost after its put (its Zenoh session, the router, the capture's){drops}")


def _readers_dropped(result: RunResult, bus: str) -> str:
    """What the userspace hub dropped for readers of the bus other than the capture (the bridge's socket
    among them) when their queue was full: a loss the bridge did not read at all (captures.json)."""
    others = [c for c in read_capture_stats(result.run_dir).get("can", {}).get("hub_other_drops", [])
              if c.get("iface") == bus]
    if not others:
        return ""
    said = ", ".join(f"{c['rx_drops']} for {c['cookie']} (queue limit {c['queue_limit']})" for c in others[:SHOW])
    return (f"; the userspace hub dropped frames for other readers of {bus} whose queue was full: {said} "
            f"(the bridge's socket, if it is one of them, never read them)")


def ordering(result: RunResult) -> list[str] | None:
    """Frames arrive in bus order, globally and per id; with a QoS table of several classes
    (bridge.rx_qos) in bus order within each class (a higher class may overtake a lower one)."""
    if not _expect(result, "ordering", True):
        return None
    table = rxqos.of_bridge(result.scenario.bridge)
    problems = []
    for b in result.buses:
        c = b.comparison
        reordered = c.reordered if table is None else rxqos.reordered_per_class(c.matched, table)
        if reordered:
            listed = "; ".join(f"{describe(s)} after {describe(p)}" for s, p in reordered[:SHOW])
            within = f"{c.reordered_per_id} within the same id" + (
                f"; judged per QoS class, {len(table.classes)} classes" if table else "")
            problems.append(f"{b.bus}: {len(reordered)} frames out of order ({within}): {listed}")
    return problems


def _latency_gate(result: RunResult, direction: str, comparisons) -> list[str] | None:
    gate = (_expect(result, "latency", {}) or {}).get(direction)
    if not gate or not ("p50_ms" in gate or "p99_ms" in gate):
        return None
    problems = []
    for bus, comparison in comparisons:
        lat = comparison.summary()["latency"]
        if lat["count"] == 0:
            continue  # nothing arrived: the integrity checks report that, latency has nothing to measure
        if "p50_ms" in gate and lat["p50_ms"] > gate["p50_ms"]:
            problems.append(f"{bus}: p50 {lat['p50_ms']:.3f} ms > gate {gate['p50_ms']} ms "
                            f"(p90 {lat['p90_ms']:.3f}, p99 {lat['p99_ms']:.3f}, max {lat['max_ms']:.3f} ms)")
        if "p99_ms" in gate and lat["p99_ms"] > gate["p99_ms"]:
            problems.append(f"{bus}: p99 {lat['p99_ms']:.3f} ms > gate {gate['p99_ms']} ms")
    return problems


def latency_can_to_zenoh(result: RunResult) -> list[str] | None:
    """Median CAN -> Zenoh latency (bus timestamp to Zenoh receive) within the gate."""
    return _latency_gate(result, "can_to_zenoh", [(b.bus, b.comparison) for b in result.buses])


def latency_zenoh_to_can(result: RunResult) -> list[str] | None:
    """Median Zenoh -> CAN latency (put to bus timestamp) within the gate."""
    return _latency_gate(result, "zenoh_to_can", [(b.bus, b.zenoh_to_can) for b in result.buses if b.zenoh_to_can])


def latency_round_trip(result: RunResult) -> list[str] | None:
    """Median round trip (put -> CAN -> echo ECU -> CAN -> Zenoh receive) within the gate."""
    return _latency_gate(result, "round_trip", [(b.bus, b.round_trip) for b in result.buses if b.round_trip])


def zenoh_to_can(result: RunResult) -> list[str] | None:
    """Every command put on a tx key reached its bus byte-exact, once, in put order, and the
    bridge put nothing else on the bus."""
    if not result.scenario.commands:
        return None
    problems = []
    for b in result.buses:
        c = b.zenoh_to_can
        if c is None or not b.commands:
            continue
        if _expect(result, "integrity", True):
            if c.lost:
                problems.append(f"{b.bus}: {len(c.lost)} commands never reached the bus: {_frames(c.lost)}")
            if c.duplicates:
                problems.append(f"{b.bus}: {len(c.duplicates)} commands written twice: {_frames(c.duplicates)}")
            if c.corrupted:
                listed = "; ".join(f"{describe(s)} reached the bus as {r.frame.candump(b.bus).split(' ', 1)[1]} "
                                   f"({describe(r)}, bytes {diff})" for s, r, diff in c.corrupted[:SHOW])
                problems.append(f"{b.bus}: {len(c.corrupted)} commands corrupted: {listed}")
            if c.unexpected:
                problems.append(f"{b.bus}: {len(c.unexpected)} frames on the bus that neither a command nor an ECU "
                                f"explains: {_frames(c.unexpected)}")
        reordered = c.reordered  # by the bridge's order (canbench.put_order), as analysis counted them
        if _expect(result, "ordering", True) and reordered:
            listed = "; ".join(f"{describe(s)} after {describe(p)}" for s, p in reordered[:SHOW])
            problems.append(f"{b.bus}: {len(reordered)} commands out of put order: {listed}")
    return problems


def round_trip(result: RunResult) -> list[str] | None:
    """Every command an echo ECU answers came back on Zenoh as its answer."""
    trips = [b for b in result.buses if b.round_trip]
    if not trips:
        return None
    problems = []
    for b in trips:
        c = b.round_trip
        assert c is not None
        if len(c.lost) > _expect(result, "loss_budget", 0):
            problems.append(f"{b.bus}: {len(c.lost)} of {c.sent} answers never came back on {b.rx_key}, "
                            f"expected: {_frames(c.lost)}")
    return problems


SAME_STAMP_SHARE = 0.01  # a bus median gap under this share of the mean gap: frames that share a stamp


JITTER_MIN_GAPS = 20  # gaps an id needs for the jitter gate: its 10th and 90th percentiles then leave out
# at least 2 gaps at each end (a late wakeup makes one long gap and one short), not the min and max


def _jitter_added(can: dict, zen: dict) -> float | None:
    """How much wider an id's gaps spread on Zenoh than on the bus, 10th to 90th percentile (None
    for an id of fewer than JITTER_MIN_GAPS gaps on either side, or metrics of a run before these
    percentiles were kept)."""
    if min(can["count"], zen["count"]) - 1 < JITTER_MIN_GAPS:
        return None
    can_p10, can_p90 = can.get("cycle_p10_ms"), can.get("cycle_p90_ms")
    zen_p10, zen_p90 = zen.get("cycle_p10_ms"), zen.get("cycle_p90_ms")
    if can_p10 is None or can_p90 is None or zen_p10 is None or zen_p90 is None:
        return None
    return (zen_p90 - zen_p10) - (can_p90 - can_p10)


def cycle_time(result: RunResult) -> list[str] | None:
    """Per id, the cycle time a Zenoh consumer sees matches the bus (median within
    tolerance_pct; the bridge widens no gap by more than (max_gap_factor - 1) x the expected cycle,
    so on a bus that keeps its cycle no gap on Zenoh is above max_gap_factor x the cycle; it
    spreads the gaps, 10th to 90th percentile, by no more than max_jitter_added_ms)."""
    gate = _expect(result, "cycle_time")
    if not gate:
        return None
    tolerance = gate.get("tolerance_pct")
    factor = gate.get("max_gap_factor")
    jitter = gate.get("max_jitter_added_ms")
    explicit = {wire.id_key(k): v for k, v in gate.get("ids", {}).items()}  # as the cycles are keyed: 11/29-bit apart
    problems = []
    seen: set[str] = set()
    for b in result.buses:
        seen.update(b.cycle_times)
        from_dbc = _dbc_cycles(result, b.bus, b.cycle_times) if gate.get("from_dbc") else None
        for ident, sides in b.cycle_times.items():
            can, zen = sides["can"], sides["zenoh"]
            if can["count"] < gate.get("min_frames", 5):
                continue
            bus_rhythm = False  # whether Zenoh is held to the bus's own median, no cycle named for the id
            if from_dbc is not None:  # the database's cycle, judged on the bus too (a wrong sender)
                if ident not in explicit and ident not in from_dbc:
                    continue  # not a cyclic message of the DBC: no cycle to expect
                cycle, message, at_most = from_dbc.get(ident, (None, "", False))
                expected = explicit.get(ident, cycle)
                name = f" ({message})" if message else ""
                if at_most and ident not in explicit:  # a cycle plus events: the longest gap
                    if tolerance is not None and can["cycle_max_ms"] > expected * (1 + tolerance / 100):
                        problems.append(f"{b.bus} id {ident}{name}: longest gap {can['cycle_max_ms']:.2f} ms on the "
                                        f"bus, the DBC's cycle of an event-periodic message (the most it may be) "
                                        f"{expected:.2f} ms +-{tolerance}%")
                    expected = can["cycle_p50_ms"]  # Zenoh keeps the bus's rhythm, events and all
                    bus_rhythm = True
                elif tolerance is not None and can["cycle_p50_ms"] is not None and \
                        abs(can["cycle_p50_ms"] - expected) > expected * tolerance / 100:
                    said = "cycle_time.ids says" if ident in explicit else "the DBC says"
                    problems.append(f"{b.bus} id {ident}{name}: median cycle {can['cycle_p50_ms']:.2f} ms on the bus, "
                                    f"{said} {expected:.2f} ms +-{tolerance}%")
                    expected = can["cycle_p50_ms"]  # the sender's fault, said once: Zenoh is judged against the bus
            else:
                expected = explicit.get(ident, can["cycle_p50_ms"])
                bus_rhythm = ident not in explicit
            if not zen:
                continue  # nothing of this id arrived: integrity reports that
            if zen["count"] < 2:
                problems.append(f"{b.bus} id {ident}: no cycle on Zenoh (1 frame)")
                continue
            # held to the bus's own median (no cycle named for it) when that median is near 0 (an id
            # sent twice a cycle under one stamp): its tolerance is of its frames' rate, the mean gap,
            # so the bridge's jitter inside a pair does not fail it. Any other median keeps its own
            # tolerance: bursts of a 10 ms id every 500 ms (mean 100 ms) delivered at once must fail
            mean = can.get("cycle_mean_ms") or 0.0
            scale = mean if bus_rhythm and expected < mean * SAME_STAMP_SHARE else expected
            if tolerance is not None and abs(zen["cycle_p50_ms"] - expected) > scale * tolerance / 100:
                said = f"+-{tolerance}%" if scale == expected else f"+-{tolerance}% of its mean gap {scale:.2f} ms"
                problems.append(f"{b.bus} id {ident}: median cycle {zen['cycle_p50_ms']:.2f} ms on Zenoh, expected "
                                f"{expected:.2f} ms {said}")
            # the gap the bridge adds (a gap the bus already had, an ECU late, is not the bridge's):
            # on a bus that keeps its cycle, a Zenoh gap over max_gap_factor x the cycle
            added = zen.get("gap_added_max_ms", zen["cycle_max_ms"] - expected)
            if factor is not None and added > expected * (factor - 1):
                problems.append(f"{b.bus} id {ident}: a gap {added:.2f} ms longer on Zenoh than on the bus (longest on "
                                f"Zenoh {zen['cycle_max_ms']:.2f} ms), more than ({factor} - 1) x {expected:.2f} ms")
            if jitter is not None and (spread := _jitter_added(can, zen)) is not None and spread > jitter:
                problems.append(f"{b.bus} id {ident}: its gaps spread {spread:.2f} ms more on Zenoh than on the bus "
                                f"(10th to 90th percentile: {zen['cycle_p10_ms']:.2f} to {zen['cycle_p90_ms']:.2f} ms "
                                f"against {can['cycle_p10_ms']:.2f} to {can['cycle_p90_ms']:.2f}), more than "
                                f"max_jitter_added_ms {jitter:g}")
    # an id cycle_time.ids names that no bus carried: its cycle was never judged (a silent sender)
    for ident in sorted(set(explicit) - seen):
        problems.append(f"id {ident}: cycle_time.ids expects it every {explicit[ident]:g} ms, but no bus carried "
                        "a frame of it")
    return problems


def _dbc_cycles(result: RunResult, bus: str, idents) -> dict:
    """id -> (GenMsgCycleTime in ms, message name, whether events come in between: the cycle is
    then the longest gap) of the ids seen (idents, as id_hex writes them) that are a cyclic
    message of the bus's DBC: its own id, or a J1939 group's from another source (dbc.message_of)."""
    path = result.scenario.bus_dbcs.get(bus)
    if not path:
        return {}
    db = load_dbc(path)
    out: dict[str, tuple[float, str, bool]] = {}
    for ident in idents:
        if (found := cycle_of_id(db, *wire.id_of(ident))) is not None:
            out[ident] = (found[1], found[0].name, send_type_at_most(found[0].send_type))
    return out


def signals_can(result: RunResult) -> list[str] | None:
    """Every gated signal (expect.signals) on the bus, decoded with the bus's DBC, met its
    expectation: what the ECUs sent is what the scenario says they send."""
    if not getattr(result.scenario, "signal_gates", ()):
        return None
    return signals.evaluate(result).problems("can")


def signals_zenoh(result: RunResult) -> list[str] | None:
    """Every gated signal decoded from the bridge's samples met its expectation: a bridge that
    corrupts a signal fails here, naming the signal, the sample and the bus frame it was."""
    if not getattr(result.scenario, "signal_gates", ()):
        return None
    return signals.evaluate(result).problems("zenoh")


def responses(result: RunResult) -> list[str] | None:
    """Each stimulus (expect.responses: a command put, or a bus signal meeting a condition) got
    its response within within_ms, once where asked, as often as count says (canbench.responses)."""
    if not _expect(result, "responses"):
        return None
    return [p for r in (result.metrics.get("responses") or {}).values() for p in r["problems"]]


def latency_regression(result: RunResult) -> list[str] | None:
    """Median latency per direction not worse than the baseline run's by more than
    max_regression_pct (differences under regression_floor_ms are noise)."""
    gates = {d: g for d, g in (_expect(result, "latency", {}) or {}).items() if "max_regression_pct" in g}
    if not gates or result.baseline is None:
        return None
    base = result.baseline
    for key in ("scenario", "schema_version"):  # another scenario's or format's numbers compare with nothing
        if base.get(key) != result.metrics.get(key):
            return [f"the baseline run {base.get('run_id')} has {key} {base.get(key)!r}, this run "
                    f"{result.metrics.get(key)!r}: no comparison (give a run of this scenario)"]
    problems = []
    for direction, gate in gates.items():
        for bus, now in result.metrics.get(direction, {}).items():
            before = base.get(direction, {}).get(bus)
            if not before or before["latency"]["p50_ms"] is None or now["latency"]["p50_ms"] is None:
                continue
            old, new = before["latency"]["p50_ms"], now["latency"]["p50_ms"]
            if new > old * (1 + gate["max_regression_pct"] / 100) and new - old > gate.get("regression_floor_ms", 0.05):
                grown = f"+{(new / old - 1) * 100:.0f}%" if old > 0 else "from a baseline of 0 or below"
                problems.append(f"{direction} {bus}: p50 {new:.3f} ms vs {old:.3f} ms in baseline run "
                                f"{base.get('run_id')} ({grown} > {gate['max_regression_pct']}%)")
    return problems


def faults_injected(result: RunResult) -> list[str] | None:
    """Every fault step of the scenario was injected (else the run proves nothing)."""
    faults = result.metrics.get("faults")
    if not result.scenario.faults:
        return None
    if not faults:
        return ["no fault was injected"]
    problems = list(faults["errors"])
    if len(faults["windows"]) < len(result.scenario.faults):
        problems.append(f"{len(faults['windows'])} of {len(result.scenario.faults)} fault steps ran")
    return problems


def recovery(result: RunResult) -> list[str] | None:
    """After each fault, frames are bridged again within the scenario's recovery gate, per direction."""
    gate = _expect(result, "recovery_s")
    faults = result.metrics.get("faults")
    if not gate or not faults:
        return None
    problems = []
    for direction, attr in (("can_to_zenoh", "comparison"), ("zenoh_to_can", "zenoh_to_can")):
        if direction not in gate:
            continue
        for b in result.buses:
            c = getattr(b, attr)
            if c is None:
                continue
            for window, seconds in zip(disruptive(faults["windows"]), c.recovery_s, strict=False):
                what = f"{b.bus} {direction} after {window['action']} (ended at {window['end_s']} s)"
                if seconds is None:
                    problems.append(f"{what}: no frame bridged after the fault")
                elif seconds > gate[direction]:
                    problems.append(f"{what}: recovered in {seconds:.3f} s > gate {gate[direction]} s")
    return problems


def bridge_memory(result: RunResult) -> list[str] | None:
    """The bridge's memory stayed under the gate (sampled every 0.5 s while faults run) and,
    in a soak, did not keep growing."""
    gate, slope_gate = _expect(result, "bridge_rss_mib"), _expect(result, "bridge_rss_slope_mib_per_h")
    faults = result.metrics.get("faults")
    if (not gate and slope_gate is None) or not faults or result.metrics.get("device"):
        return None
    rss = faults["bridge_rss_mib"]
    if rss["max"] is None:
        return ["no memory sample of the bridge"]
    problems = []
    if gate and rss["max"] > gate:
        problems.append(f"bridge memory peaked at {rss['max']:.1f} MiB > gate {gate} MiB")
    if slope_gate is not None:
        if rss["slope_mib_per_h"] is None:
            problems.append(f"too few memory samples ({rss['samples']}) for a slope")
        elif rss["slope_mib_per_h"] > slope_gate:
            problems.append(f"bridge memory grows {rss['slope_mib_per_h']} MiB/h > gate {slope_gate} MiB/h")
    return problems


def bridge_fds(result: RunResult) -> list[str] | None:
    """The bridge's open file descriptors did not grow over the run (soak)."""
    gate = _expect(result, "bridge_fd_growth")
    faults = result.metrics.get("faults")
    if gate is None or not faults or result.metrics.get("device"):
        return None
    fds = faults["bridge_fds"]
    if fds["growth"] is None:
        return [f"too few descriptor samples ({fds['samples']}) to tell growth"]
    return [f"bridge descriptors grew by {fds['growth']} > gate {gate}"] if fds["growth"] > gate else []


def only_expected_keys(result: RunResult) -> list[str] | None:
    """The bridge published on its own keys only."""
    keys = result.unexpected_keys  # all of them in metrics.json unexpected_keys
    if not keys:
        return []
    return [f"samples on {len(keys)} unexpected keys: {_listed(keys, repr)}"]


def ecus_sent_their_traces(result: RunResult) -> list[str] | None:
    """Every ECU finished and the bus capture holds all it sent (the bench lost nothing)."""
    problems = [f"{e.name}: no summary" for e in result.scenario.ecus if e.name not in result.ecus]
    sent = sum(s["sent"] for s in result.ecus.values())
    for b in result.buses:
        if b.ecu_frames_not_captured:
            problems.append(f"{b.bus}: {b.ecu_frames_not_captured} of the frames the ECUs sent ({sent} in all) are "
                            "missing from the bus capture: the bench lost frames")
    return problems


def _since_last_restart(result: RunResult, frames):
    """The frames of the bridge's last incarnation: its counters start again at 0 when a fault
    step restarts it, so compare only what arrived after that."""
    restarted_ns = last_bridge_restart_ns((result.metrics.get("faults") or {}).get("windows", []))
    return [f for f in frames if f.t_ns >= restarted_ns]


def bridge_stats_agree(result: RunResult) -> list[str] | None:
    """The bridge's own counters agree with what the oracle saw."""
    if result.metrics.get("device_announces") is False:
        return None  # a device with no stats queryable (skip_reason)
    if result.bridge_stats is None:
        return ["the bridge's stats queryable did not answer"]
    problems = []
    for b in result.buses:
        bus_stats = next((s for s in result.bridge_stats["buses"] if s["bus"] == b.bus), None)
        if bus_stats is None:
            problems.append(f"no stats for {b.bus}")
            continue
        received = len(_since_last_restart(result, b.zenoh_frames))
        # a put into a link a fault step has cut succeeds locally: those frames are the
        # fault's loss, counted in lost_in_faults, and may be missing here too
        in_faults = len(b.comparison.lost_in_faults)
        published = bus_stats["published_frames"]
        if not received <= published <= received + in_faults:
            problems.append(f"{b.bus}: bridge says it published {published} frames, the capture received "
                            f"{received}" + (f" (+{in_faults} lost inside fault windows)" if in_faults else ""))
        tx = b.zenoh_to_can
        if tx is not None:
            restarted_ns = last_bridge_restart_ns((result.metrics.get("faults") or {}).get("windows", []))
            written = sum(1 for r in [r for _, r in tx.matched] + tx.duplicates + [r for _, r, _ in tx.corrupted]
                          + tx.unexpected if r.t_ns >= restarted_ns)
            if bus_stats["tx_frames"] != written:
                problems.append(f"{b.bus}: bridge says it wrote {bus_stats['tx_frames']} frames to CAN, "
                                f"the bus carried {written} from it")
    return problems


def freshness(result: RunResult) -> dict:
    """Per bus, what no_stale_commands judges (kept in metrics.json as `freshness`): the deadline;
    how many commands reached the bus and how many of them later than the deadline after their
    source time (put time, less stamp_age_ms), the largest such age; the bridge's tx_rejected.stale;
    the commands stamped too old when put and refused; the commands lost inside fault windows, per
    window (what the bridge's stale refusals are attributed to)."""
    if "freshness" in result.metrics:
        return result.metrics["freshness"]
    deadline_ms = result.scenario.tx_max_age_ms
    ages, aged_out = stamp_ages_ns(result.scenario), stale_at_put(result.scenario)
    windows = disruptive((result.metrics.get("faults") or {}).get("windows", []))
    floods = [(w["start_ns"], (w["end_ns"] or w["start_ns"]) + FAULT_SETTLE_NS)
              for w in windows if w["action"] == FLOOD_ACTION]
    out = {}
    for b in result.buses:
        c = b.zenoh_to_can
        if c is None or not b.commands:
            continue
        def key(o, bus=b.bus):
            return (bus, o.frame.can_id, o.frame.extended)
        pairs = list(c.matched) + [(s, r) for s, r, _ in c.corrupted]
        aged = [(s, r, (r.t_ns - s.t_ns + ages.get(key(s), 0)) / 1e6) for s, r in pairs]
        over = sorted((a for a in aged if a[2] > deadline_ms + FRESHNESS_SLACK_MS), key=lambda a: -a[2])
        late: list[tuple] = []
        late_in_floods: list[tuple] = []
        for a in over:
            (late_in_floods if any(start <= a[1].t_ns <= end for start, end in floods) else late).append(a)
        per_window = [{"action": w["action"], "start_s": w.get("start_s"), "lost": 0} for w in windows]
        stamped_refused, in_faults = explained_refusals(b.bus, b.commands, c, aged_out)
        refused_late = getattr(b, "refused_late", [])
        for o in in_faults:
            at = [i for i, w in enumerate(windows) if w["start_ns"] - FAULT_LEAD_NS <= o.t_ns]
            if at:
                per_window[at[-1]]["lost"] += 1
        stats = bus_stats(result.bridge_stats, b.bus)
        out[b.bus] = {
            "deadline_ms": deadline_ms,
            "slack_ms": FRESHNESS_SLACK_MS,
            "reached_bus": len(pairs),
            "late": len(late),
            "max_age_ms": round(max((a[2] for a in aged), default=0.0), 3),
            "late_examples": [f"{describe(s)} reached the bus {age:.1f} ms after its source time ({describe(r)})"
                              for s, r, age in late[:10]],
            "late_in_floods": len(late_in_floods),
            "late_in_floods_examples": [f"{describe(s)} reached the bus {age:.1f} ms after its source time "
                                        f"({describe(r)}), during a flood" for s, r, age in late_in_floods[:10]],
            "refused_stale": (stats or {}).get("tx_rejected", {}).get("stale"),
            "stamped_stale": sum(1 for s in b.commands if key(s) in aged_out),
            "stamped_stale_refused": stamped_refused,
            "lost_in_faults": len(in_faults),
            "lost_per_window": per_window,
            "refused_after_late_delivery": len(refused_late),
            "refused_late_examples": [f"{describe(o)}: " + (
                f"the next {o.frame.can_id:X} reached the bus {upper:.1f} ms after this one's source time"
                if shown_by == "bus" else
                f"the bridge counted every command of the bus only {upper:.1f} ms after this one's source time "
                "(the commander's fence)") for o, upper, shown_by in refused_late[:10]],
        }
    result.metrics["freshness"] = out
    return out


def no_stale_commands(result: RunResult) -> list[str] | None:
    """Every command that reached the bus did so within the bridge's deadline (bridge.tx_max_age_ms)
    of its source time, and what the bridge refused as stale (tx_rejected.stale) is explained: commands
    stamped too old when put, or lost inside a fault window (a stalled link delivers them late)."""
    if not result.scenario.commands or not result.scenario.tx_max_age_ms:
        return None
    problems = []
    for bus, f in freshness(result).items():
        if f["late"]:
            problems.append(f"{bus}: {f['late']} of {f['reached_bus']} commands reached the bus older than the "
                            f"deadline {f['deadline_ms']} ms + {f['slack_ms']} ms (oldest {f['max_age_ms']:.1f} ms): "
                            + "; ".join(f["late_examples"]) + (" ..." if f["late"] > len(f["late_examples"]) else ""))
        late = f.get("refused_after_late_delivery", 0)
        explained = f["stamped_stale_refused"] + f["lost_in_faults"] + late
        if f["refused_stale"] is not None and f["refused_stale"] > explained:
            problems.append(f"{bus}: the bridge refused {f['refused_stale']} commands as stale; only {explained} are "
                            f"explained ({f['stamped_stale_refused']} stamped too old when put, {f['lost_in_faults']} "
                            f"lost inside fault windows, {late} delivered late): commands refused without a "
                            "stalled link")
    return problems


_BRIDGE_CHECKS: dict[str, Callable[[RunResult], list[str] | None]] = {
    "integrity": integrity,
    "ordering": ordering,
    "latency_can_to_zenoh": latency_can_to_zenoh,
    "zenoh_to_can": zenoh_to_can,
    "latency_zenoh_to_can": latency_zenoh_to_can,
    "round_trip": round_trip,
    "latency_round_trip": latency_round_trip,
    "cycle_time": cycle_time,
    "signals_can": signals_can,
    "signals_zenoh": signals_zenoh,
    "responses": responses,
    "latency_regression": latency_regression,
    "faults_injected": faults_injected,
    "recovery": recovery,
    "bridge_memory": bridge_memory,
    "bridge_fds": bridge_fds,
    "only_expected_keys": only_expected_keys,
    "ecus_sent_their_traces": ecus_sent_their_traces,
    "bridge_stats_agree": bridge_stats_agree,
    "no_stale_commands": no_stale_commands,
}
CHECKS: dict[str, Callable[[RunResult], list[str] | None]] = {
    "valid_run": valid_run, **{name: _on_the_bridge(check) for name, check in _BRIDGE_CHECKS.items()},
    # the router's access control (the security scenario, canbench.security): judged on every run,
    # a late emulator does not make an intruder's session any less of one
    "access_control": security.check}


def failing(result: RunResult) -> dict[str, list[str]]:
    """The checks that fail on this result, with their problems."""
    out = {}
    for name, check in CHECKS.items():
        problems = check(result)
        if problems:
            out[name] = problems
    return out
