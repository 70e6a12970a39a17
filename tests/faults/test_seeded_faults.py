"""The bench must catch a broken bridge: each seeded fault of
zenoh-node-faulty (ZN_FAULT=...) runs a shipped scenario (smoke for CAN ->
Zenoh, round-trip for Zenoh -> CAN and back) through the real orchestrator
(pytest --pyargs canbench.scenario_checks, as in compose) with its ECUs on the host bus, and
exactly the checks that guard against that fault must fail, naming the
affected frames. The same binary without a fault must pass everything. Beside the
shipped scenarios, small ones of this directory: signal-flip.yaml (signal gates for a
flip inside EngineSpeed), cycle-jitter.yaml (the cycle-time jitter gate) and
restbus-cycle.yaml / restbus-wrong-cycle.yaml (a restbus ECU at the DBC's cycles, and the
same ECU with a wrong one: the ECU's fault)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml
from conftest import BRIDGE, REPO
from fault_run import run_case

from canbench import oracle, scenario

FAULTY = Path(os.environ.get("ZN_BRIDGE_FAULTY", BRIDGE.with_name("zenoh-node-faulty")))
SMOKE = REPO / "scenarios" / "smoke.yaml"
ROUND_TRIP = REPO / "scenarios" / "round-trip.yaml"
STALE = REPO / "scenarios" / "stale-commands.yaml"  # run without its fault steps (they need Docker)
SIGNALS = REPO / "scenarios" / "signals.yaml"
SIGNAL_FLIP = Path(__file__).with_name("signal-flip.yaml")  # EngineSpeed and three other signals gated
RESTBUS = Path(__file__).with_name("restbus-cycle.yaml")    # a restbus BODY node, cycle times from the DBC
RESTBUS_WRONG = Path(__file__).with_name("restbus-wrong-cycle.yaml")  # the same, BodyStatus 80 ms (DBC: 50)
JITTER = Path(__file__).with_name("cycle-jitter.yaml")  # smoke's replay with cycle_time.max_jitter_added_ms 3

# (scenario, fault, extra bridge options) -> the checks that must fail (and only those)
CASES = {
    (SMOKE, "", ()): set(),
    (SMOKE, "drop:10", ()): {"integrity", "bridge_stats_agree"},     # lost frames; the bridge claims it sent them
    (SMOKE, "dup:10", ()): {"integrity", "bridge_stats_agree"},      # duplicates; counted once by the bridge
    (SMOKE, "swap:10", ()): {"ordering"},
    (SMOKE, "flip:10", ()): {"integrity"},                           # corrupted bytes, counts still agree
    (SMOKE, "delay:20", ()): {"latency_can_to_zenoh"},               # smoke gates p50 at 5 ms
    (SMOKE, "wrongkey", ()): {"integrity", "only_expected_keys", "bridge_stats_agree"},
    # a bridge that bunches frames (misconfigured batching) breaks the cycle times consumers see
    (SMOKE, "", ("--publish-period-ms", "100")): {"cycle_time", "latency_can_to_zenoh"},
    (ROUND_TRIP, "", ()): set(),
    # Zenoh -> CAN: a command silently not written never gets its answer either
    (ROUND_TRIP, "txdrop:10", ()): {"zenoh_to_can", "round_trip", "bridge_stats_agree"},
    # a corrupted command reaches the bus; the echo answers what it got, not what was asked
    (ROUND_TRIP, "txflip:10", ()): {"zenoh_to_can", "round_trip"},
    (STALE, "", ()): set(),
    # commands stamped 400 ms before their put (deadline 100 ms) are written instead of refused
    (STALE, "no-freshness", ()): {"no_stale_commands"},
    (SIGNALS, "", ()): set(),
    # every answer reaches Zenoh 300 ms late: the stimulus-response check (within 150 ms), nothing else
    (SIGNALS, "delay:300", ()): {"responses"},
    (SIGNAL_FLIP, "", ()): set(),
    # bit 7 of byte 2 (EngineSpeed's top bit) in every 5th frame: that signal's Zenoh-side gate, and integrity
    (SIGNAL_FLIP, "flip:5@2.7", ()): {"integrity", "signals_zenoh"},
    (JITTER, "", ()): set(),
    # every sample held 0..10 ms at random, in order: the gaps spread, the median cycle holds
    (JITTER, "jitter:10", ()): {"cycle_time"},
    (RESTBUS, "", ()): set(),
    # the ECU's fault, not the bridge's: BodyStatus every 80 ms where the DBC says 50
    (RESTBUS_WRONG, "", ()): {"cycle_time"},
}


def case_id(case) -> str:
    scenario, fault, options = case
    fault_id = fault.replace(":", "").replace("@", "at")  # flip5at2.7: -k cannot parse an @
    return "-".join([scenario.stem, fault_id or "none", *[o.strip("-") for o in options]])


@pytest.mark.parametrize("case", list(CASES), ids=[case_id(c) for c in CASES])
def test_seeded_fault_fails_exactly_its_checks(bus, router, tmp_path, case):
    scenario_path, fault, options = case
    if not FAULTY.exists():
        pytest.skip(f"{FAULTY} not built (make firmware)")
    sc = scenario.load(scenario_path)
    if sc.faults:  # fault steps drive Docker: on the host, the same scenario without them
        doc = yaml.safe_load(scenario_path.read_text())
        doc.pop("faults")
        scenario_path = tmp_path / scenario_path.name
        scenario_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    run = run_case(bus, router, tmp_path, FAULTY, scenario_path, fault, f"fault-{case_id(case)}", options)
    metrics = run.metrics
    print(run.orchestrator.stdout[-6000:], run.orchestrator.stderr[-3000:])
    assert run.failed == CASES[case], metrics["problems"]
    assert (run.orchestrator.returncode == 0) == (not CASES[case])
    if sc.commands:  # the commander's fence: the bridge counted every command soon after the last put
        arrived = json.loads((run.run_dir / "commands-arrived.json").read_text())
        last_put_ns = max(r.t_ns for r in oracle.read_sent_log(run.run_dir / "commands.tsv"))
        for bus_name, a in arrived.items():
            assert a["all_arrived_by_ns"] is not None, (bus_name, a, "the fence timed out")
            assert 0 <= a["all_arrived_by_ns"] - last_put_ns < 2 * 10**9, (bus_name, a, last_put_ns)
    # failures point at the frames: bus capture or command log lines, or sequence numbers on the Zenoh side
    for check in CASES[case] & {"integrity", "ordering", "zenoh_to_can", "round_trip"}:
        assert any("can.log:" in p or "commands.tsv:" in p or "seq" in p for p in metrics["problems"][check]), \
            metrics["problems"][check]
    if "signals_zenoh" in CASES[case]:  # the flipped signal alone, at its values and frames
        assert [p.split(":")[0] for p in metrics["problems"]["signals_zenoh"]] == ["vcan0 EngineData.EngineSpeed"], \
            metrics["problems"]["signals_zenoh"]
        assert " rpm outside [1000, 15000] at t=" in metrics["problems"]["signals_zenoh"][0]
        assert "(sent as can.log:" in metrics["problems"]["signals_zenoh"][0]
    if scenario_path == RESTBUS_WRONG:  # BodyStatus alone (0x320), named with the DBC's cycle
        assert all("id 320" in p for p in metrics["problems"]["cycle_time"]), metrics["problems"]["cycle_time"]
        assert any("(BodyStatus)" in p and "the DBC says 50.00 ms" in p for p in metrics["problems"]["cycle_time"])
    if "responses" in CASES[case]:  # each late answer names its stimulus's put
        assert all("commands.tsv:" in p and " late, after " in p for p in metrics["problems"]["responses"]), \
            metrics["problems"]["responses"]
