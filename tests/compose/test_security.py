"""The bench's access control in compose, as `make test` runs it (scripts/bench-run): the
security scenario passes with mutual TLS and the default-deny ACL on (the default) - a client
without a certificate and a bridge with another CA's certificate get no session, the ECUs'
identity gets one but none of its commands reach the bridge or the bus - and the run's
private keys are gone afterwards. With BENCH_ACCESS=open (no TLS, no ACL) the same scenario
fails: the probes' frames reach the bus. docs/access-control.md. Needs the images."""
from __future__ import annotations

import json

import pytest
from test_compose import REPO, bench_run, junit_cases, leftovers

SCENARIO = REPO / "scenarios" / "security.yaml"
pytestmark = pytest.mark.compose


def test_security_scenario_passes_with_access_control_on():
    proc, run_dir = bench_run(SCENARIO)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    seen = json.loads((run_dir / "security.json").read_text())
    probes = seen["probes"]
    for name in ("anonymous", "rogue-bridge"):
        assert probes[name]["session"] is False, probes[name]
        assert all(not a["session"] and a["error"] for a in probes[name]["attempts"]), probes[name]
    assert [a["endpoint"] for a in probes["anonymous"]["attempts"]] == ["tls/router:7447", "tcp/router:7447"]
    assert probes["ecu"]["session"] is True and probes["ecu"]["put"] == 20, probes["ecu"]
    assert probes["ecu"]["capture_ready_seen"] is True  # it put while the bridge and the capture were up
    assert seen["rogue_bridge_tokens"] == []
    metrics = json.loads((run_dir / "metrics.json").read_text())
    tx = metrics["zenoh_to_can"]["vcan0"]
    # every command got through the access control: on the bus, or to the bridge, which refused it as
    # delivered too late for its deadline (a loaded machine; no_stale_commands explains each)
    late = metrics["freshness"]["vcan0"]["refused_after_late_delivery"]
    assert tx["unexpected"] == 0 and tx["matched"] + late == tx["sent"] > 0 and late <= 2, (tx, late)
    cases = junit_cases(run_dir)
    for check in ("access_control", "zenoh_to_can", "bridge_stats_agree", "integrity"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    # the run's identities existed only while it ran: no private key left anywhere
    assert not (REPO / "build" / "runs" / f"{run_dir.name}.identities").exists()
    assert not list(run_dir.rglob("*.pem"))
    assert leftovers(run_dir) == []


def test_without_access_control_the_probes_reach_the_bus():
    proc, run_dir = bench_run(SCENARIO, BENCH_ACCESS="open")
    assert proc.returncode == 1, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert "BENCH_ACCESS=open" in proc.stdout
    seen = json.loads((run_dir / "security.json").read_text())
    assert all(p["session"] for p in seen["probes"].values()), seen
    metrics = json.loads((run_dir / "metrics.json").read_text())
    problems = metrics["problems"]["access_control"]
    assert any("the router gave it a session" in p for p in problems), problems
    # what the probes put got through: onto the bus, or at least to the bridge
    assert any("reached the bus" in p or "came from a probe" in p for p in problems), problems
    assert junit_cases(run_dir)["test_check[access_control]"] == "failed"
    assert leftovers(run_dir) == []
