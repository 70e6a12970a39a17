"""The shipped real-vehicle scenarios can fail: a seeded fault of zenoh-node-faulty on the
recorded 2016 Dodge Caravan diagnostic traffic (tests/data/traces/pyvit/README; most frames
repeat byte for byte, so matching by content is put to the test) fails exactly the checks
meant for it, through the real orchestrator with its ECU on the host bus, as
test_seeded_faults.py does for the synthetic traces. The same binary without a fault passes."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from conftest import BRIDGE, REPO, Bridge, zenoh_session

from canbench import scenario

FAULTY = BRIDGE.with_name("zenoh-node-faulty")
CANDUMP = REPO / "scenarios" / "dodge-caravan-cdr.yaml"    # candump -L section
ASC = REPO / "scenarios" / "dodge-caravan-cdr-asc.yaml"    # Vector ASC section
RUN_TIMEOUT_S = 120

CASES = {
    (CANDUMP, ""): set(),
    (CANDUMP, "drop:10"): {"integrity", "bridge_stats_agree"},  # lost frames the bridge counts as sent
    (ASC, "swap:10"): {"ordering"},
}


def run(bus, router, tmp_path, scenario_path: Path, fault: str) -> dict:
    sc = scenario.load(scenario_path)
    bridge = Bridge(bus, router)
    bridge.binary = FAULTY
    bus.env["ZN_FAULT"] = fault
    bus.env["PATH"] = f"{bus.tool('')}:{bus.env['PATH']}"  # ucanctl for the capture's readiness check
    ecus = []
    try:
        bridge.start("--can", ",".join(sc.bus_names), "--publish-period-ms",
                     str(sc.bridge.get("publish_period_ms", 0)), "--tx-max-age-ms", str(sc.tx_max_age_ms))
        session = zenoh_session(router.endpoint)
        bridge.wait_ready(session)
        session.close()
        run_dir = tmp_path / "run"
        common = ["--scenario", str(scenario_path), "--run-id", f"real-{scenario_path.stem}",
                  "--run-dir", str(run_dir), "--router", router.endpoint]
        ecus = [bus.popen([sys.executable, "-m", "canbench.cli", "ecu", "--name", e.name, *common])
                for e in sc.ecus]
        orchestrator = bus.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                "--pyargs", "canbench.scenario_checks", *common], check=False,
                               timeout=RUN_TIMEOUT_S, cwd=REPO)
        for ecu in ecus:
            assert ecu.wait(timeout=RUN_TIMEOUT_S) == 0, ecu.stderr.read()
        metrics = json.loads((run_dir / "metrics.json").read_text())
        metrics["_returncode"] = orchestrator.returncode
        return metrics
    finally:
        for ecu in ecus:
            if ecu.poll() is None:
                ecu.kill()
        if bridge.proc and bridge.proc.poll() is None:
            bridge.stop()


@pytest.mark.parametrize("case", list(CASES), ids=[f"{s.stem}-{f.replace(':', '') or 'none'}" for s, f in CASES])
def test_real_trace_fault_fails_exactly_its_checks(bus, router, tmp_path, case):
    if not FAULTY.exists():
        pytest.skip(f"{FAULTY} not built (make firmware)")
    scenario_path, fault = case
    metrics = run(bus, router, tmp_path, scenario_path, fault)
    failed = {check.split("[")[1].rstrip("]") for check, outcome in metrics["verdicts"].items()
              if outcome == "failed"}
    assert failed == CASES[case], metrics["problems"]
    assert (metrics["_returncode"] == 0) == (not CASES[case])
    side = metrics["can_to_zenoh"]["vcan0"]
    if fault.startswith("drop:"):  # every 10th frame lost, named by its capture line
        assert side["lost"] > 0 and side["duplicates"] == 0, side
        assert any("can.log:" in p for p in metrics["problems"]["integrity"]), metrics["problems"]["integrity"]
    if fault.startswith("swap:"):  # reordered, nothing lost: repeated contents do not hide a swap
        assert side["reordered"] > 0 and side["lost"] == 0, side
