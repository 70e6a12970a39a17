"""Runs one scenario from the orchestrator's side: wait for the bridge's
liveliness token, start both captures, tell the ECUs to go (a liveliness
token), wait for every ECU's done message, drain, stop, analyse, and write
metrics.json. The pytest checks (tests/scenarios) read the result."""
from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import oracle, runkeys
from .capture import CanCapture, ZenohCapture, read_zenoh_capture
from .scenario import Scenario

METRICS_SCHEMA_VERSION = 1
BRIDGE_READY_TIMEOUT_S = 60
DRAIN_TIMEOUT_S = 5.0


@dataclass
class BusResult:
    bus: str
    rx_key: str
    can_frames: list[oracle.Observed]
    zenoh_frames: list[oracle.Observed]
    comparison: oracle.Comparison
    problems: list[str]


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


def rx_key(prefix: str, bus: str, bus_count: int) -> str:
    return f"{prefix}/rx" if bus_count == 1 else f"{prefix}/{bus}/rx"


def query_stats(session, prefix: str) -> dict | None:
    replies = [r for r in session.get(f"{prefix}/bridges/*/stats") if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


def execute(scenario: Scenario, run_id: str, run_dir: Path, router: str, prefix: str = "vehicle/can") -> RunResult:
    run_dir.mkdir(parents=True, exist_ok=True)
    session = runkeys.open_session(router)
    try:
        runkeys.wait_token(session, f"{prefix}/bridges/**", BRIDGE_READY_TIMEOUT_S)
        done: dict[str, dict] = {}
        all_done = threading.Event()
        names = {e.name for e in scenario.ecus}

        def on_done(sample) -> None:
            name = str(sample.key_expr).split("/")[-2]
            done[name] = json.loads(sample.payload.to_bytes())
            if names <= set(done):
                all_done.set()

        done_sub = session.declare_subscriber(f"bench/runs/{run_id}/ecus/*/done", on_done)
        can_capture = CanCapture(run_dir / "can.log", scenario.bus_names)
        zenoh_capture = ZenohCapture(session, f"{prefix}/**")
        ready = session.liveliness().declare_token(runkeys.capture_ready(run_id))
        started = time.monotonic()
        try:
            if not all_done.wait(scenario.duration_s + 30):
                missing = sorted(names - set(done))
                raise TimeoutError(f"ECUs {missing} did not finish within duration_s + 30 s "
                                   f"({scenario.duration_s + 30:.0f} s); see their container logs")
            traffic_s = time.monotonic() - started
            # drain: until the bridge has published everything it read, or a bounded wait
            period_s = scenario.bridge.get("publish_period_ms", 0) / 1000

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
            ready.undeclare()
            done_sub.undeclare()
            can_capture.stop()
            zenoh_capture.stop(run_dir / "zenoh.jsonl")
    finally:
        session.close()
    return analyse(scenario, run_id, run_dir, prefix, done, bridge_stats, traffic_s)


def analyse(scenario: Scenario, run_id: str, run_dir: Path, prefix: str, ecus: dict[str, dict],
            bridge_stats: dict | None, traffic_s: float) -> RunResult:
    samples = read_zenoh_capture(run_dir / "zenoh.jsonl")
    expected_keys = {rx_key(prefix, b, len(scenario.bus_names)) for b in scenario.bus_names}
    expected_keys |= {k.replace("/rx", "/tx") for k in expected_keys}
    unexpected_keys = sorted({key for _, key, _, _ in samples if key not in expected_keys})
    buses = []
    for bus in scenario.bus_names:
        key = rx_key(prefix, bus, len(scenario.bus_names))
        can_frames = oracle.read_candump(run_dir / "can.log", bus)
        zenoh_frames, problems = oracle.zenoh_frames(samples, key)
        buses.append(BusResult(bus, key, can_frames, zenoh_frames, oracle.compare(can_frames, zenoh_frames), problems))
    result = RunResult(scenario, run_id, run_dir, buses, ecus, bridge_stats, unexpected_keys)
    result.metrics = {
        "schema_version": METRICS_SCHEMA_VERSION,
        "run_id": run_id,
        "scenario": scenario.name,
        "traffic_s": round(traffic_s, 3),
        "can_to_zenoh": {b.bus: b.comparison.summary() for b in buses},
        "cycle_times": {b.bus: oracle.cycle_times(b.can_frames) for b in buses},
        "ecus": ecus,
        "bridge_stats": bridge_stats,
        "unexpected_keys": unexpected_keys,
        "verdicts": {},
    }
    write_metrics(result)
    return result


def write_metrics(result: RunResult) -> None:
    path = result.run_dir / "metrics.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.metrics, indent=2, default=str))
    tmp.replace(path)  # never a half-written file
