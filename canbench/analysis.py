"""The analysis of a run: the captures, send logs and ECU summaries a run left in its directory,
compared by the oracle per bus (CAN -> Zenoh, Zenoh -> CAN, round trips through echo ECUs), into
a RunResult and metrics.json. Needs no network: checks, reports and tests use it on a directory."""
from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from . import oracle, signals, wire
from .capture import iter_zenoh_capture
from .commands import delivered_late, explained_refusals, read_arrivals, stale_at_put, stamp_ages_ns
from .faults import cutting, disruptive
from .put_order import overtaken_commands
from .runkeys import rx_key, tx_key
from .scenario import Scenario

METRICS_SCHEMA_VERSION = 1


@dataclass
class BusResult:
    bus: str
    rx_key: str
    can_frames: list[oracle.Observed]
    zenoh_frames: list[oracle.Observed]
    comparison: oracle.Comparison       # CAN -> Zenoh
    problems: list[str]
    commands: list[oracle.Observed] = field(default_factory=list)
    zenoh_to_can: oracle.Comparison | None = None
    round_trip: oracle.Comparison | None = None
    cycle_times: dict = field(default_factory=dict)  # id -> {"can": stats, "zenoh": stats}
    bus_frames: list[oracle.Observed] = field(default_factory=list)  # the whole bus capture
    ecu_frames_not_captured: int = 0  # frames an ECU logged as sent that the bus capture lacks
    # commands the bridge refused as stale after a late delivery (commands.delivered_late), with the
    # upper bound of their age in ms and what showed it ("bus", "fence"): not lost (zenoh_to_can),
    # explained (no_stale_commands)
    refused_late: list[tuple[oracle.Observed, float, str]] = field(default_factory=list)


@dataclass
class RunResult:
    scenario: Scenario
    run_id: str
    run_dir: Path
    buses: list[BusResult]
    ecus: dict[str, dict]
    bridge_stats: dict | None
    unexpected_keys: list[str]
    metrics: dict = field(default_factory=dict)
    baseline: dict | None = None  # metrics.json of the run to compare with (relative regression gate)


Located = list[tuple[str, oracle.Observed]]  # (bus, frame)


def expected_answers(scenario: Scenario, commands: Located) -> Located:
    """(bus, the echo's answer) for every command an echo ECU answers; the answer carries the
    command's put time and place, so latency is the round trip and failures name the command."""
    out = []
    for bus, cmd in commands:
        f = cmd.frame
        echo = next((e for e in scenario.echoes if e.bus == bus and f.can_id in e.echo_ids), None)
        if echo is None or f.remote:
            continue
        can_id, data = echo.answer(f.can_id, f.data)
        out.append((bus, oracle.Observed(wire.Frame(can_id, f.dlc, data, f.extended), cmd.t_ns, cmd.index,
                                         line=cmd.line, origin=cmd.origin)))
    return out


def answer_ids(scenario: Scenario) -> dict[str, set[int]]:
    """Per bus: the ids of echo answers."""
    out: dict[str, set[int]] = {}
    for e in scenario.echoes:
        out.setdefault(e.bus, set()).update(i + e.answer_id_offset for i in e.echo_ids)
    return out


def _sent_by_ecus(run_dir: Path, bus: str) -> Counter:
    """What the ECUs on this bus say they sent (their send logs), by frame content."""
    out: Counter = Counter()
    for log in sorted(run_dir.glob("ecu-*.sent.tsv")):
        out.update(oracle.frame_key(r.frame) for r in oracle.read_sent_log(log) if r.bus == bus)
    return out


def _flood_frames(scenario: Scenario, bus: str, can_frames: list[oracle.Observed]) -> Counter:
    """The frames of the bus's can_flood steps, by content (told by their id, the flood's alone)."""
    ids = {f.can_id for f in scenario.faults if f.action == "can_flood" and f.bus == bus}
    return Counter(oracle.frame_key(o.frame) for o in can_frames if o.frame.can_id in ids and not o.frame.extended)


def _cycle_times(can_frames: list[oracle.Observed], matched: list[tuple[oracle.Observed, oracle.Observed]]) -> dict:
    can_side = oracle.cycle_times(can_frames)
    in_order = sorted(matched, key=lambda pair: pair[1].index)
    zenoh_side = oracle.cycle_times(r for _, r in in_order)
    for ident, added in _gaps_added(in_order).items():
        zenoh_side[ident]["gap_added_max_ms"] = added
    return {ident: {"can": stats, "zenoh": zenoh_side.get(ident)} for ident, stats in can_side.items()}


def _gaps_added(in_order: list[tuple[oracle.Observed, oracle.Observed]]) -> dict[str, float]:
    """Per id, the most the bridge widened a gap: of two frames one after the other on Zenoh, their
    gap there minus their gap on the bus. A gap the bus already had (an ECU late, a frame lost
    before the bridge) is not the bridge's."""
    last: dict[tuple, tuple[int, int]] = {}
    out: dict[str, float] = {}
    for sent, received in in_order:
        key = (sent.frame.can_id, sent.frame.extended)
        if key in last:
            bus_t, zen_t = last[key]
            ident = wire.id_hex(*key)
            added = ((received.t_ns - zen_t) - (sent.t_ns - bus_t)) / 1e6
            out[ident] = max(out.get(ident, added), added)
        last[key] = (sent.t_ns, received.t_ns)
    return {ident: round(v, 3) for ident, v in out.items()}


def analyse(scenario: Scenario, run_id: str, run_dir: Path, prefix: str, ecus: dict[str, dict],
            bridge_stats: dict | None, traffic_s: float, baseline: dict | None = None,
            faults: dict | None = None) -> RunResult:
    n = len(scenario.bus_names)
    rx_keys = {rx_key(prefix, b, n) for b in scenario.bus_names}
    on_zenoh, keys_seen = oracle.zenoh_frames_by_key(iter_zenoh_capture(run_dir / "zenoh.tsv"), rx_keys)
    expected_keys = rx_keys | {tx_key(prefix, b, n) for b in scenario.bus_names}
    unexpected_keys = sorted(keys_seen - expected_keys)
    commands_log = run_dir / "commands.tsv"
    commands = [(r.bus, oracle.Observed(r.frame, r.t_ns, i, line=r.log_line, origin="commands.tsv"))
                for i, r in enumerate(oracle.read_sent_log(commands_log) if commands_log.exists() else [])]
    answers = expected_answers(scenario, commands)
    arrivals = read_arrivals(commands_log)
    buses = []
    windows = [(w["start_ns"], w["end_ns"]) for w in disruptive(faults["windows"])] if faults else []
    cuts = [(w["start_ns"], w["end_ns"]) for w in cutting(faults["windows"])] if faults else []
    for bus in scenario.bus_names:
        key = rx_key(prefix, bus, n)
        can_frames = oracle.read_candump(run_dir / "can.log", bus)
        zenoh_frames, problems = on_zenoh[key]
        bus_commands = [c for b, c in commands if b == bus]
        tx = None
        from_ecus = can_frames
        sent_by_ecus = _sent_by_ecus(run_dir, bus)
        if scenario.commands:
            # every bus frame not from an ECU or a flood is the bridge's
            tx, from_ecus = oracle.compare_commands(bus_commands, can_frames,
                                                    sent_by_ecus + _flood_frames(scenario, bus, can_frames))
            # out of order as the bridge keeps order (arbitration among waiting commands), as the verdict counts
            tx.reordered = overtaken_commands(tx.matched)
            tx.counts["reordered"] = len(tx.reordered)
            tx.reordered_per_id = sum(s.frame.can_id == p.frame.can_id and s.frame.extended == p.frame.extended
                                      for s, p in tx.reordered)
        comparison = oracle.compare(from_ecus, zenoh_frames, windows, cuts)
        bus_answers = [a for b, a in answers if b == bus]
        round_trip = oracle.match_subset(bus_answers, zenoh_frames) if bus_answers else None
        for c in (tx, round_trip):
            if c is not None and windows:
                oracle.apply_fault_windows(c, windows)
        stale = stale_at_put(scenario)
        if tx is not None and stale:
            # stamped older than the deadline when put: the bridge must refuse them, no loss of zenoh_to_can's
            # (checks.no_stale_commands judges them)
            kept = [o for o in tx.lost if (bus, o.frame.can_id, o.frame.extended) not in stale]
            tx.counts["lost"] -= len(tx.lost) - len(kept)  # metrics.json's count, as the check's list
            tx.lost = kept
        refused_late = (_refused_late(scenario, bus, bus_commands, tx, stale, bridge_stats, arrivals.get(bus))
                        if tx is not None else [])
        not_captured = sum((sent_by_ecus - Counter(oracle.frame_key(o.frame) for o in can_frames)).values())
        buses.append(BusResult(bus, key, from_ecus, zenoh_frames, comparison, problems, bus_commands, tx, round_trip,
                               _cycle_times(from_ecus, comparison.matched), can_frames, not_captured, refused_late))
    result = RunResult(scenario, run_id, run_dir, buses, ecus, bridge_stats, unexpected_keys, baseline=baseline)
    result.metrics = {
        "schema_version": METRICS_SCHEMA_VERSION,
        "run_id": run_id,
        "scenario": scenario.name,
        "traffic_s": round(traffic_s, 3),
        "can_to_zenoh": {b.bus: b.comparison.summary() for b in buses},
        "zenoh_to_can": {b.bus: b.zenoh_to_can.summary() for b in buses if b.zenoh_to_can},
        "round_trip": {b.bus: b.round_trip.summary() for b in buses if b.round_trip},
        "cycle_times": {b.bus: b.cycle_times for b in buses},
        "ecus": ecus,
        "bridge_stats": bridge_stats,
        "unexpected_keys": unexpected_keys,
        "baseline_run_id": baseline.get("run_id") if baseline else None,
        "faults": faults,
        "verdicts": {},
    }
    if scenario.signal_gates:  # per gated signal, side and bus: count, min, max, violations
        result.metrics["signals"] = signals.evaluate(result).summary()
    if scenario.expect.get("responses"):  # stimulus-response checks: counts, latencies, problems
        result.metrics["responses"] = _responses(scenario, commands, buses)
    write_metrics(result)
    return result


def bus_stats(bridge_stats: dict | None, bus: str) -> dict | None:
    """One bus's entry of the bridge's stats (None without stats or that bus)."""
    return next((s for s in (bridge_stats or {}).get("buses", []) if s["bus"] == bus), None)


def _refused_late(scenario: Scenario, bus: str, commands: list[oracle.Observed], tx: oracle.Comparison,
                  stale: set, bridge_stats: dict | None,
                  arrived_by_ns: int | None = None) -> list[tuple[oracle.Observed, float, str]]:
    """The lost commands the bridge refused as stale because the link delivered them late (a stalled
    router or machine, outside any fault window), taken out of tx.lost: as many as the bridge's
    tx_rejected.stale leaves unexplained by commands stamped too old and fault windows, each one
    shown late by the next command of its id or, for a stream's last ones, by the commander's fence
    (arrived_by_ns; commands.delivered_late). A bridge that loses commands
    without counting them as stale, or refuses fresh ones, is not excused."""
    if not scenario.tx_max_age_ms or not tx.lost:
        return []
    refused = (bus_stats(bridge_stats, bus) or {}).get("tx_rejected", {}).get("stale") or 0
    stamped_refused, in_faults = explained_refusals(bus, commands, tx, stale)
    budget = refused - stamped_refused - len(in_faults)
    if budget <= 0:
        return []
    late = delivered_late(bus, tx.lost, tx.matched, stamp_ages_ns(scenario), scenario.tx_max_age_ms * 1_000_000,
                          arrived_by_ns)
    late = late[:budget]
    excused = {id(o) for o, _, _ in late}
    tx.lost = [o for o in tx.lost if id(o) not in excused]
    tx.counts["lost"] -= len(late)
    return late


def _responses(scenario: Scenario, commands: Located, buses: list[BusResult]) -> dict:
    from . import responses
    from .dbc import load_dbc

    def refused(where: list, message: str) -> None:  # canbench.scenario refused these already
        raise ValueError(f"{'.'.join(map(str, where))}: {message}")
    return responses.evaluate_all(responses.rules(scenario.raw, scenario.bus_dbcs, load_dbc, refused), commands, buses)


def write_metrics(result: RunResult) -> None:
    path = result.run_dir / "metrics.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.metrics, indent=2, default=str))
    tmp.replace(path)  # never a half-written file
