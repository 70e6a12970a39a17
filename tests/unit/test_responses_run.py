"""The shipped signals scenario, as a synthetic run analysed as a bench run is: its ECUs' plans
(the engine's replay, the BODY restbus), its commands in signals put on the tx key and written
to the bus, the responder's answers (made by its rule) on the bus and on Zenoh. A bridge that
publishes with a fixed delay fails the response check and nothing else."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import analysis, checks, commands, plans, scenario, wire
from canbench.plans import SENT_LOG_HEADER, frame_of, sent_line

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
T0 = 1_800_000_000_000_000_000  # ns: the run's start
MS = 1_000_000


def synthetic_signals_run(run_dir: Path, publish_delay_ms: float) -> analysis.RunResult:
    sc = scenario.load(REPO / "scenarios" / "signals.yaml")
    bus: list[tuple[int, wire.Frame]] = []  # (bus time, frame)
    ecus = {}
    for e in sc.ecus:
        if e.role == "responder":
            continue
        plan = plans.schedule(e, sc)
        with open(run_dir / f"ecu-{e.name}.sent.tsv", "w") as log:
            log.write(SENT_LOG_HEADER)
            for line, m in plan.frames():
                t = T0 + int(m.timestamp * 1e9)
                log.write(sent_line(line, t - 50_000, frame_of(m), "vcan0"))
                bus.append((t, frame_of(m)))
        ecus[e.name] = {"name": e.name, "role": e.role, "bus": "vcan0", "sent": plan.count}
    responder = next(e for e in sc.ecus if e.role == "responder")
    rule = responder.rules[0]
    with open(run_dir / "commands.tsv", "w") as log, open(run_dir / f"ecu-{responder.name}.sent.tsv", "w") as answers:
        log.write(SENT_LOG_HEADER)
        answers.write(SENT_LOG_HEADER)
        for n, (offset, _, line, frame) in enumerate(commands.plan(sc)):
            put = T0 + int(offset * 1e9) + 3 * MS  # clear of the ECUs' frames at the same offsets
            log.write(sent_line(line, put, frame, "vcan0"))
            bus.append((put + 1 * MS, frame))  # the bridge writes it
            message, data = rule.answer(frame.data, n)
            answer = wire.Frame(message.frame_id, message.length, data)
            answers.write(sent_line(0, put + 2 * MS, answer, "vcan0"))
            bus.append((put + 2 * MS, answer))
    ecus[responder.name] = {"name": responder.name, "role": "responder", "bus": "vcan0",
                            "sent": len(commands.plan(sc))}
    bus.sort(key=lambda tf: tf[0])
    commanded = {wire.encode(f) for _, _, _, f in commands.plan(sc)}
    with open(run_dir / "can.log", "w") as can_log, open(run_dir / "zenoh.tsv", "w") as zen:
        for i, (t, f) in enumerate(bus):
            can_log.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
            if wire.encode(f) in commanded:
                continue  # the bridge's own writes are not read back
            zen.write(f"{t + int((0.4 + publish_delay_ms) * MS)}\tvehicle/can/rx\t{wire.encode(f).hex()}\t"
                      f"{wire.encode_attachment(i, [t // 1000 * 1000]).hex()}\n")
    return analysis.analyse(sc, "synthetic-signals", run_dir, "vehicle/can", ecus, None, 3.0)


def failing(result) -> dict:
    out = checks.failing(result)
    out.pop("bridge_stats_agree", None)  # no bridge here to ask
    return out


def test_the_signals_scenario_passes_on_a_prompt_bridge(tmp_path):
    result = synthetic_signals_run(tmp_path, 0.0)
    assert failing(result) == {}
    r = result.metrics["responses"]
    assert (r["torque-50"]["stimuli"], r["torque-50"]["answered"]) == (3, 3)
    assert (r["torque-any"]["stimuli"], r["torque-any"]["answered"]) == (5, 5)
    assert r["torque-any"]["latency"]["p50_ms"] == pytest.approx(2.4, abs=0.01)  # put -> answer on Zenoh


def test_a_bridge_with_a_fixed_delay_fails_the_response_check_and_nothing_else(tmp_path):
    result = synthetic_signals_run(tmp_path, 300.0)
    failed = failing(result)
    assert set(failed) == {"responses"}, failed
    assert len(failed["responses"]) == 8  # every answer of both rules
    assert all("commands.tsv:" in p and "late, after 302.400 ms (within 150 ms)" in p for p in failed["responses"])


def test_report_html_shows_each_response_checks_counts_and_latency(tmp_path):
    from canbench import report
    result = synthetic_signals_run(tmp_path, 300.0)
    report.write_html(result, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    section = page.split("<h2>Responses</h2>", 1)[1].split("<h2>", 1)[0]
    assert "<td>torque-50</td><td>vcan0</td><td>zenoh</td><td>150.0</td><td>3</td><td>0</td><td>3</td>" in section
    assert "<td>302.400</td>" in section  # the late answers' latency (none answered in time)
