"""The bench must catch a broken bridge: each seeded fault of
zenoh-node-faulty (ZN_FAULT=...) runs the smoke scenario through the real
orchestrator (pytest tests/scenarios, as in compose) on the host bus, and
exactly the checks that guard against that fault must fail, naming the
affected frames. The same binary without a fault must pass everything."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
from conftest import BRIDGE, REPO, Bridge, zenoh_session

FAULTY = Path(os.environ.get("ZN_BRIDGE_FAULTY", BRIDGE.with_name("zenoh-node-faulty")))
SCENARIO = REPO / "scenarios" / "smoke.yaml"
RUN_TIMEOUT_S = 120

# fault -> the checks that must fail (and only those)
FAULTS = {
    "": set(),
    "drop:10": {"integrity", "bridge_stats_agree"},        # lost frames; the bridge claims it sent them
    "dup:10": {"integrity", "bridge_stats_agree"},         # duplicates; counted once by the bridge
    "swap:10": {"ordering"},
    "flip:10": {"integrity"},                              # corrupted bytes, counts still agree
    "delay:20": {"latency_can_to_zenoh"},                  # smoke gates p50 at 5 ms
    "wrongkey": {"integrity", "only_expected_keys", "bridge_stats_agree"},
}


@pytest.mark.parametrize("fault", list(FAULTS), ids=[f or "none" for f in FAULTS])
def test_seeded_fault_fails_exactly_its_checks(bus, router, tmp_path, fault):
    if not FAULTY.exists():
        pytest.skip(f"{FAULTY} not built (make firmware)")
    bridge = Bridge(bus, router)
    bridge.binary = FAULTY
    bus.env["ZN_FAULT"] = fault
    bus.env["PATH"] = f"{bus.tool('')}:{bus.env['PATH']}"  # ucanctl for the capture's readiness check
    try:
        bridge.start("--can", "vcan0", "--publish-period-ms", "0")
        with_session = zenoh_session(router.endpoint)
        bridge.wait_ready(with_session)
        with_session.close()
        run_dir = tmp_path / "run"
        common = ["--scenario", str(SCENARIO), "--run-id", f"fault-{fault or 'none'}", "--run-dir", str(run_dir),
                  "--router", router.endpoint]
        ecu = bus.popen([sys.executable, "-m", "canbench.cli", "ecu", "--name", "engine", *common])
        orchestrator = bus.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                str(REPO / "tests" / "scenarios"), *common], check=False, timeout=RUN_TIMEOUT_S,
                               cwd=REPO)
        assert ecu.wait(timeout=RUN_TIMEOUT_S) == 0, ecu.stderr.read()
        metrics = json.loads((run_dir / "metrics.json").read_text())
    finally:
        if bridge.proc and bridge.proc.poll() is None:
            bridge.stop()
        print(bridge.log.read_text()[-3000:] if bridge.log.exists() else "")
    failed = {check.split("[")[1].rstrip("]") for check, outcome in metrics["verdicts"].items()
              if outcome == "failed"}
    print(orchestrator.stdout[-6000:], orchestrator.stderr[-3000:])
    assert failed == FAULTS[fault], metrics["problems"]
    assert (orchestrator.returncode == 0) == (not FAULTS[fault])
    # failures point at the frames: bus capture lines, or sequence numbers on the Zenoh side
    for check in FAULTS[fault] & {"integrity", "ordering"}:
        assert any("can.log:" in p or "seq" in p for p in metrics["problems"][check]), metrics["problems"][check]
