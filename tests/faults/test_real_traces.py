"""The shipped real-vehicle scenarios can fail: a seeded fault of zenoh-node-faulty on the
recorded 2016 Dodge Caravan diagnostic traffic (tests/data/traces/pyvit/README; most frames
repeat byte for byte, so matching by content is put to the test) fails exactly the checks
meant for it, through the real orchestrator with its ECU on the host bus, as
test_seeded_faults.py does for the synthetic traces. The same binary without a fault passes."""
from __future__ import annotations

import pytest
from conftest import BRIDGE, REPO
from fault_run import run_case

FAULTY = BRIDGE.with_name("zenoh-node-faulty")
CANDUMP = REPO / "scenarios" / "dodge-caravan-cdr.yaml"    # candump -L section
ASC = REPO / "scenarios" / "dodge-caravan-cdr-asc.yaml"    # Vector ASC section

CASES = {
    (CANDUMP, ""): set(),
    (CANDUMP, "drop:10"): {"integrity", "bridge_stats_agree"},  # lost frames the bridge counts as sent
    (ASC, "swap:10"): {"ordering"},
}


@pytest.mark.parametrize("case", list(CASES), ids=[f"{s.stem}-{f.replace(':', '') or 'none'}" for s, f in CASES])
def test_real_trace_fault_fails_exactly_its_checks(bus, router, tmp_path, case):
    if not FAULTY.exists():
        pytest.skip(f"{FAULTY} not built (make firmware)")
    scenario_path, fault = case
    run = run_case(bus, router, tmp_path, FAULTY, scenario_path, fault, f"real-{scenario_path.stem}")
    metrics = run.metrics
    assert run.failed == CASES[case], metrics["problems"]
    assert (run.orchestrator.returncode == 0) == (not CASES[case])
    side = metrics["can_to_zenoh"]["vcan0"]
    if fault.startswith("drop:"):  # every 10th frame lost, named by its capture line
        assert side["lost"] > 0 and side["duplicates"] == 0, side
        assert any("can.log:" in p for p in metrics["problems"]["integrity"]), metrics["problems"]["integrity"]
    if fault.startswith("swap:"):  # reordered, nothing lost: repeated contents do not hide a swap
        assert side["reordered"] > 0 and side["lost"] == 0, side
