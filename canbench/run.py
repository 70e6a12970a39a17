"""Runs one scenario from the orchestrator's side: wait for the bridge's
liveliness token (through the consumer's path) and for every echo ECU's, start
both captures, tell the ECUs to go (a liveliness token), put the commands on
the tx keys, wait for every ECU's done message, let the echoes stop, drain,
stop, analyse, and write metrics.json. The pytest checks (tests/scenarios)
read the result."""
from __future__ import annotations

import json
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from . import oracle, ros2, runkeys, wire
from .capture import CanCapture, ZenohCapture, read_zenoh_capture
from .commands import Commander, tx_key
from .commands import plan as command_plan
from .faults import Injector, disruptive
from .scenario import Scenario

METRICS_SCHEMA_VERSION = 1
BRIDGE_READY_TIMEOUT_S = 60
DRAIN_TIMEOUT_S = 5.0
ECHO_STOP_TIMEOUT_S = 15
PROGRESS_EVERY_S = 2.0


def progress(line: str) -> None:
    """One line on the real stderr (pytest captures the rest), for long runs."""
    print(f"canbench: {line}", file=sys.__stderr__, flush=True)


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


def rx_key(prefix: str, bus: str, bus_count: int) -> str:
    return f"{prefix}/rx" if bus_count == 1 else f"{prefix}/{bus}/rx"


def query_stats(session, prefix: str) -> dict | None:
    replies = [r for r in session.get(f"{prefix}/bridges/*/stats") if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


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


def _answer_ids(scenario: Scenario) -> dict[str, set[int]]:
    """Per bus: the ids of echo answers."""
    out: dict[str, set[int]] = {}
    for e in scenario.echoes:
        out.setdefault(e.bus, set()).update(i + e.answer_id_offset for i in e.echo_ids)
    return out


def execute(scenario: Scenario, run_id: str, run_dir: Path, router: str, prefix: str = "vehicle/can",
            consumer: str | None = None, baseline: dict | None = None, project: str | None = None,
            wait_viewer: bool = False) -> RunResult:
    """router: where the bench coordinates (ECUs, stats); consumer: where the capture and the
    commands connect (the router by default; a far router or the bridge itself by topology);
    project: the compose project, for fault steps; wait_viewer: a `canbench view` records the
    run (make test VIEWER=1), the traffic starts once its token says it subscribes."""
    run_dir.mkdir(parents=True, exist_ok=True)
    session = runkeys.open_session(router)
    data = session if consumer in (None, router) else runkeys.open_session(consumer)
    try:
        # the token seen through the consumer's path: the data path is up end to end
        runkeys.wait_token(data, f"{prefix}/bridges/**", BRIDGE_READY_TIMEOUT_S)
        for e in scenario.echoes:
            runkeys.wait_token(session, runkeys.ecu_ready(run_id, e.name), BRIDGE_READY_TIMEOUT_S)
        if wait_viewer:
            runkeys.wait_token(session, "canbench/viewers/*", BRIDGE_READY_TIMEOUT_S)
            wanted = set(ros2_data_keys(scenario))
            runkeys.wait_until(lambda: wanted <= viewer_subscriptions(session), BRIDGE_READY_TIMEOUT_S,
                               "the viewer subscribed to the bridge's ROS 2 topic", step_s=0.1)
        done: dict[str, dict] = {}
        senders_done = threading.Event()
        echoes_done = threading.Event()
        senders = {e.name for e in scenario.ecus if e.role != "echo"}
        echo_names = {e.name for e in scenario.echoes}

        def on_done(sample) -> None:
            name = str(sample.key_expr).split("/")[-2]
            done[name] = json.loads(sample.payload.to_bytes())
            if senders <= set(done):
                senders_done.set()
            if echo_names <= set(done):
                echoes_done.set()

        done_sub = session.declare_subscriber(f"bench/runs/{run_id}/ecus/*/done", on_done)
        can_capture = CanCapture(run_dir / "can.log", scenario.bus_names)
        zenoh_capture = ZenohCapture(data, consumer or router, f"{prefix}/**", run_dir / "zenoh.tsv",
                                     runkeys.zenoh_capture_ready(run_id))
        commander = Commander(data, scenario, run_dir / "commands.tsv", prefix) if scenario.commands else None
        injector = None
        if scenario.faults:
            if not project:
                raise RuntimeError("this scenario has fault steps: they need the compose project (BENCH_PROJECT) "
                                   "and Docker's socket, i.e. a run by make test / scripts/bench-run")

            def ecu_killed(name: str) -> None:
                log = run_dir / f"ecu-{name}.sent.tsv"
                sent = sum(1 for line in open(log) if not line.startswith("#")) if log.exists() else 0
                done[name] = {"name": name, "killed": True, "sent": sent}
                if senders <= set(done):
                    senders_done.set()
            injector = Injector(project, scenario.faults, ecu_killed)
        ready = session.liveliness().declare_token(runkeys.capture_ready(run_id))
        started = time.monotonic()
        if injector:
            injector.start()
        all_keys = {rx_key(prefix, b, len(scenario.bus_names)) for b in scenario.bus_names}
        bridge_stats = None
        try:
            if commander:
                commander.start()
            deadline = scenario.duration_s + 30
            # progress while the traffic runs; the wait itself is on the ECUs' done messages
            while not senders_done.wait(PROGRESS_EVERY_S) and time.monotonic() - started < deadline:
                # an ECU's done message can be lost while a fault step has the router down;
                # its summary file (written whole before the message) says the same
                for name in senders - set(done):
                    summary_file = run_dir / f"ecu-{name}.json"
                    if summary_file.exists():
                        done[name] = json.loads(summary_file.read_text())
                if senders <= set(done):
                    senders_done.set()
                    break
                progress(f"{time.monotonic() - started:5.1f} s of up to {scenario.duration_s:g} s: "
                         f"{len(set(done) & senders)}/{len(senders)} ECUs done, "
                         f"{zenoh_capture.frames_on(all_keys)} frames on Zenoh"
                         + (f", {commander.sent}/{len(commander.items)} commands put" if commander else ""))
            if not senders_done.is_set():
                missing = sorted(senders - set(done))
                raise TimeoutError(f"ECUs {missing} did not finish within duration_s + 30 s "
                                   f"({deadline:.0f} s); see their container logs")
            if commander:
                commander.join(max(0.0, deadline - (time.monotonic() - started)))
                if commander.is_alive():
                    raise TimeoutError(f"commands not all put within duration_s + 30 s ({deadline:.0f} s)")
                if commander.error:
                    raise RuntimeError(f"putting commands failed: {commander.error}")
            if injector:
                injector.wait_faults(deadline)
            traffic_s = time.monotonic() - started
            period_s = scenario.bridge.get("publish_period_ms", 0) / 1000
            if commander:
                _drain_commands(session, data, prefix, commander.sent, scenario, zenoh_capture, period_s)
            if echo_names:
                session.put(runkeys.ecu_stop(run_id), b"")
                if not echoes_done.wait(ECHO_STOP_TIMEOUT_S):
                    raise TimeoutError(f"echo ECUs {sorted(echo_names - set(done))} did not stop within "
                                       f"{ECHO_STOP_TIMEOUT_S} s; see their container logs")

            # drain: until the bridge has published everything it read, or a bounded wait
            def drained() -> bool:
                stats = query_stats(session, prefix)
                if not stats:
                    return False
                read = sum(b["can_rx_frames"] - b["filtered"] - b["rx_queue_drops"] for b in stats["buses"])
                published = sum(b["published_frames"] + b["publish_errors"] for b in stats["buses"])
                return published >= read
            try:
                runkeys.wait_until(drained, DRAIN_TIMEOUT_S + period_s, "the bridge to publish what it read")
            except TimeoutError:
                pass  # whatever is missing now is the bridge's loss, which the checks report
            bridge_stats = query_stats(session, prefix)
            # samples still in flight from the router to us: until we hold all it published
            published = sum(b["published_frames"] for b in bridge_stats["buses"]) if bridge_stats else 0
            keys = {rx_key(prefix, b, len(scenario.bus_names)) for b in scenario.bus_names}
            try:
                runkeys.wait_until(lambda: zenoh_capture.frames_on(keys) >= published, 2 + period_s,
                                   "published frames to reach the capture")
            except TimeoutError:
                pass  # reported as loss by the checks
        finally:
            if injector:
                injector.stop()
            ready.undeclare()
            done_sub.undeclare()
            can_capture.stop()
            zenoh_capture.stop()
    finally:
        if data is not session:
            data.close()
        session.close()
    return analyse(scenario, run_id, run_dir, prefix, done, bridge_stats, traffic_s, baseline,
                   injector.summary() if injector else None)


def _drain_commands(session, data, prefix: str, sent: int, scenario: Scenario, capture: ZenohCapture,
                    period_s: float) -> None:
    """Bounded waits until the bridge has handled every command it was sent, and the
    echoes' answers to them are back on Zenoh; what is missing then is loss."""
    def handled() -> bool:
        stats = query_stats(session, prefix)
        return stats is not None and sum(b["tx_frames"] + b["can_tx_errors"] + sum(b["tx_rejected"].values())
                                   for b in stats["buses"]) >= sent
    try:
        runkeys.wait_until(handled, DRAIN_TIMEOUT_S, "the bridge to write the commands to CAN")
    except TimeoutError:
        return
    answer_ids = _answer_ids(scenario)
    if not answer_ids:
        return
    wanted = len(expected_answers(scenario, [(bus, oracle.Observed(frame, 0, 0))
                                            for _, bus, _, frame in command_plan(scenario)]))
    keys = {rx_key(prefix, b, len(scenario.bus_names)): ids for b, ids in answer_ids.items()}
    try:
        runkeys.wait_until(lambda: capture.frames_with_ids(keys) >= wanted, DRAIN_TIMEOUT_S + period_s,
                           "the echoes' answers to reach the capture")
    except TimeoutError:
        pass


def ros2_data_keys(scenario: Scenario) -> list[str]:
    """The data keys of the bridge's ROS 2 output (bridge.ros2_topic), one per bus."""
    topic = scenario.bridge.get("ros2_topic")
    if not topic:
        return []
    topics = [topic] if len(scenario.bus_names) == 1 else [f"{topic}/{b}" for b in scenario.bus_names]
    frame = "can_msgs/msg/Frame"
    return [ros2.data_key(scenario.bridge.get("ros2_domain", 0), t, frame, ros2.type_hash(frame)) for t in topics]


def viewer_subscriptions(session) -> set[str]:
    """What the viewers on the network subscribe to (their stats queryables)."""
    out: set[str] = set()
    for reply in session.get("canbench/viewers/*/stats"):
        if reply.ok:
            out |= set(json.loads(reply.ok.payload.to_bytes()).get("subscriptions", []))
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
    zenoh_side = oracle.cycle_times(sorted((r for _, r in matched), key=lambda o: o.index))
    return {ident: {"can": stats, "zenoh": zenoh_side.get(ident)} for ident, stats in can_side.items()}


def analyse(scenario: Scenario, run_id: str, run_dir: Path, prefix: str, ecus: dict[str, dict],
            bridge_stats: dict | None, traffic_s: float, baseline: dict | None = None,
            faults: dict | None = None) -> RunResult:
    samples = read_zenoh_capture(run_dir / "zenoh.tsv")
    n = len(scenario.bus_names)
    expected_keys = {rx_key(prefix, b, n) for b in scenario.bus_names}
    expected_keys |= {tx_key(prefix, b, n) for b in scenario.bus_names}
    unexpected_keys = sorted({key for _, key, _, _ in samples if key not in expected_keys})
    commands_log = run_dir / "commands.tsv"
    commands = [(r.bus, oracle.Observed(r.frame, r.t_ns, i, line=r.log_line, origin="commands.tsv"))
                for i, r in enumerate(oracle.read_sent_log(commands_log) if commands_log.exists() else [])]
    answers = expected_answers(scenario, commands)
    buses = []
    for bus in scenario.bus_names:
        key = rx_key(prefix, bus, n)
        can_frames = oracle.read_candump(run_dir / "can.log", bus)
        zenoh_frames, problems = oracle.zenoh_frames(samples, key)
        bus_commands = [c for b, c in commands if b == bus]
        tx = None
        from_ecus = can_frames
        sent_by_ecus = _sent_by_ecus(run_dir, bus)
        if scenario.commands:
            # every bus frame not from an ECU or a flood is the bridge's
            tx, from_ecus = oracle.compare_commands(bus_commands, can_frames,
                                                    sent_by_ecus + _flood_frames(scenario, bus, can_frames))
        comparison = oracle.compare(from_ecus, zenoh_frames)
        bus_answers = [a for b, a in answers if b == bus]
        round_trip = oracle.match_subset(bus_answers, zenoh_frames) if bus_answers else None
        if faults:
            windows = [(w["start_ns"], w["end_ns"]) for w in disruptive(faults["windows"])]
            for c in (comparison, tx, round_trip):
                if c is not None:
                    oracle.apply_fault_windows(c, windows)
        not_captured = sum((sent_by_ecus - Counter(oracle.frame_key(o.frame) for o in can_frames)).values())
        buses.append(BusResult(bus, key, from_ecus, zenoh_frames, comparison, problems, bus_commands, tx, round_trip,
                               _cycle_times(from_ecus, comparison.matched), can_frames, not_captured))
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
    write_metrics(result)
    return result


def write_metrics(result: RunResult) -> None:
    path = result.run_dir / "metrics.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.metrics, indent=2, default=str))
    tmp.replace(path)  # never a half-written file
