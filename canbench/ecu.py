"""An emulated ECU: replays its trace on its bus with the recorded timing
(python-can MessageSync), logs what it sent and when, and reports its own
timing fidelity so a verdict never blames the bridge for emulator jitter.

The ECU waits for the run's capture to be ready (a liveliness token the
orchestrator declares), then replays, then publishes its summary on
bench/runs/<run-id>/ecus/<name>/done and exits."""
from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

import can

from . import runkeys
from .scenario import Ecu, Scenario
from .trace import read_trace


def schedule(ecu: Ecu, scenario: Scenario) -> list[tuple[int, can.Message]]:
    """(trace line, message) in send order, with speed, loops, offset and id remap applied."""
    frames = read_trace(ecu.trace, None) if ecu.trace else []
    if not frames:
        return []
    t0 = frames[0].message.timestamp
    span = frames[-1].message.timestamp - t0
    period = span + (frames[1].message.timestamp - t0 if len(frames) > 1 else 0.001)
    out = []
    for loop in range(ecu.loops):
        for tf in frames:
            m = tf.message
            offset = ecu.start_offset_s + (m.timestamp - t0 + loop * period) / ecu.speed
            out.append((tf.line, can.Message(
                timestamp=offset, arbitration_id=ecu.id_remap.get(m.arbitration_id, m.arbitration_id),
                is_extended_id=m.is_extended_id, is_remote_frame=m.is_remote_frame, dlc=m.dlc,
                data=b"" if m.is_remote_frame else m.data, channel=ecu.bus)))
    return out


def percentile(values: list[float], q: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def replay(ecu: Ecu, scenario: Scenario, run_dir: Path) -> dict:
    plan = schedule(ecu, scenario)
    sent_log = run_dir / f"ecu-{ecu.name}.sent.tsv"
    errors_ms: list[float] = []
    with can.Bus(interface="socketcan", channel=ecu.bus) as bus, open(sent_log, "w") as log:
        log.write("# trace_line\tsend_time_ns\tframe\n")
        start = time.perf_counter()
        wall0 = time.time_ns() - int(start * 1e9)
        messages = [m for _, m in plan]
        # MessageSync sleeps until each message's offset: the recorded timing
        for (line, msg), synced in zip(plan, can.MessageSync(messages, timestamps=True, skip=3600), strict=True):
            bus.send(synced)
            now = time.perf_counter()
            errors_ms.append((now - start - msg.timestamp) * 1000)
            log.write(f"{line}\t{wall0 + int(now * 1e9)}\t{msg.arbitration_id:X}#{msg.data.hex().upper()}\n")
    return {
        "name": ecu.name, "bus": ecu.bus, "trace": str(ecu.trace), "sent": len(plan),
        "fidelity_ms": {"p50": round(percentile(errors_ms, 0.5), 3), "p99": round(percentile(errors_ms, 0.99), 3),
                        "max": round(max(errors_ms, default=0.0), 3),
                        "mean": round(statistics.fmean(errors_ms), 3) if errors_ms else 0.0},
    }


def run(scenario: Scenario, name: str, run_id: str, run_dir: Path, router: str, timeout_s: float) -> dict:
    ecu = next((e for e in scenario.ecus if e.name == name), None)
    if ecu is None:
        raise SystemExit(f"{scenario.path}: no ECU named {name!r}")
    session = runkeys.open_session(router)
    try:
        runkeys.wait_token(session, runkeys.capture_ready(run_id), timeout_s)
        summary = replay(ecu, scenario, run_dir)
        (run_dir / f"ecu-{ecu.name}.json").write_text(json.dumps(summary, indent=2))
        session.put(runkeys.ecu_done(run_id, name), json.dumps(summary))
        return summary
    finally:
        session.close()
