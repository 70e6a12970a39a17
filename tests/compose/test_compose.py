"""The bench in compose, as `make test` runs it (scripts/bench-run): the smoke
scenario passes with every report written; a scenario whose gate cannot be
met fails on exactly that check; an invalid run is run again and still fails;
an invalid scenario stops with exit code 2 before anything runs; no containers, networks or volumes are left behind.
Needs the images (make images) and a running Docker daemon."""
from __future__ import annotations

import json
import os
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from canbench import wire
from canbench.capture import iter_zenoh_capture

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "compose"
RUN_TIMEOUT_S = 300

pytestmark = pytest.mark.compose


def bench_run(scenario: Path, **env: str) -> tuple[subprocess.CompletedProcess, Path | None]:
    image = f"canbench/orchestrator:{os.environ.get('BENCH_TAG', 'latest')}"
    if subprocess.run(["docker", "image", "inspect", image], capture_output=True).returncode != 0:
        # make check-compose builds them first: there a missing image is an error, never a skip
        if os.environ.get("BENCH_REQUIRE_IMAGES"):
            pytest.fail(f"{image} does not exist although make built the images")
        pytest.skip("bench images not built (make images)")
    proc = subprocess.run([str(REPO / "scripts" / "bench-run"), str(scenario)], capture_output=True, text=True,
                          timeout=RUN_TIMEOUT_S, cwd=REPO, env={**os.environ, **env})
    run_dirs = attempts(proc)
    return proc, REPO / run_dirs[-1] if run_dirs else None  # the last attempt's verdict counts


def attempts(proc: subprocess.CompletedProcess) -> list[str]:
    """The run directory of every attempt bench-run made, in order."""
    marker = "(reports in "
    return [line.split(marker)[1].rstrip(")") for line in proc.stdout.splitlines() if marker in line]


def leftovers(run_dir: Path) -> list[str]:
    project = "bench-" + "".join(c if c.isalnum() or c == "\n" else "-" for c in run_dir.name.lower())
    out = []
    for kind in ("ps -a", "network ls", "volume ls"):
        label = f"label=com.docker.compose.project={project}"
        names = subprocess.run(["docker", *kind.split(), "-q", "--filter", label],
                               capture_output=True, text=True).stdout.split()
        out += [f"{kind}: {n}" for n in names]
    return out


def junit_cases(run_dir: Path) -> dict[str, str]:
    cases = {}
    for case in ET.parse(run_dir / "junit.xml").iter("testcase"):
        outcome = "failed" if case.find("failure") is not None or case.find("error") is not None else (
            "skipped" if case.find("skipped") is not None else "passed")
        cases[case.get("name")] = outcome
    return cases


def test_smoke_scenario_passes_and_writes_reports():
    proc, run_dir = bench_run(REPO / "scenarios" / "smoke.yaml")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert run_dir is not None
    for name in ("junit.xml", "metrics.json", "can.log", "zenoh.tsv", "report.html", "recording.mcap",
                 "ecu-engine.json", "containers.log"):
        assert (run_dir / name).is_file(), name
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["schema_version"] == 1 and metrics["passed"] is True
    assert metrics["can_to_zenoh"]["vcan0"]["matched"] == metrics["ecus"]["engine"]["sent"] > 0
    cases = junit_cases(run_dir)
    assert "failed" not in cases.values(), cases
    # what smoke asks for ran and passed; checks it does not ask for are skipped, never silently passed
    for check in ("integrity", "ordering", "latency_can_to_zenoh", "cycle_time", "bridge_stats_agree"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    assert cases["test_check[round_trip]"] == "skipped"
    assert (REPO / "reports" / "latest").resolve() == run_dir.resolve()
    assert leftovers(run_dir) == []


def test_failing_gate_fails_the_run_on_that_check_only():
    proc, run_dir = bench_run(DATA / "latency-gate-too-tight.yaml")
    assert proc.returncode != 0 and "FAILED" in proc.stdout
    cases = junit_cases(run_dir)
    assert cases["test_check[latency_can_to_zenoh]"] == "failed"
    assert [name for name, outcome in cases.items() if outcome == "failed"] == ["test_check[latency_can_to_zenoh]"]
    assert "gate 0.001 ms" in (run_dir / "junit.xml").read_text()
    assert json.loads((run_dir / "metrics.json").read_text())["passed"] is False
    assert leftovers(run_dir) == []


def test_fault_scenario_with_unmeetable_recovery_gate_fails_on_recovery_only():
    proc, run_dir = bench_run(DATA / "recovery-gate-too-tight.yaml")
    assert proc.returncode != 0, proc.stdout[-4000:]
    cases = junit_cases(run_dir)
    assert [name for name, outcome in cases.items() if outcome == "failed"] == ["test_check[recovery]"], cases
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["faults"]["windows"][0]["action"] == "router_kill"
    assert "recovered in" in metrics["problems"]["recovery"][0]
    assert leftovers(run_dir) == []


def test_viewer_records_the_scenarios_traffic():
    """make test VIEWER=1: `canbench view --save` in the compose project records what crossed
    the bridge; read back with Rerun's reader it holds every captured frame and its DBC signals,
    on the bridge's key and again through its ROS 2 topic (discovered by @ros2_lv, CDR)."""
    viewer = pytest.importorskip("canbench.viewer", reason="reading .rrd needs rerun-sdk (pip install -e '.[viewer]')")
    proc, run_dir = bench_run(REPO / "scenarios" / "ros2-output.yaml", VIEWER="1")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    logged = viewer.read_rrd(run_dir / "traffic.rrd")
    on_zenoh: dict[str, int] = {}
    for sample in iter_zenoh_capture(run_dir / "zenoh.tsv"):
        if not sample.key.endswith("/rx"):
            continue
        for f in wire.decode_batch(sample.payload):
            ident = wire.id_hex(f.can_id, f.extended)
            on_zenoh[ident] = on_zenoh.get(ident, 0) + 1
    def recorded(prefix: str) -> dict[str, int]:
        return {path[len(prefix):-len("/raw")]: len(v) for path, v in logged.items()
                if path.startswith(prefix) and path.endswith("/raw")}

    assert recorded("/can/rx/vcan0/") == on_zenoh
    assert recorded("/ros2/vehicle/can/") == on_zenoh
    assert len(logged["/can/rx/vcan0/0C0/EngineSpeed"]) == on_zenoh["0C0"]  # DBC-decoded
    assert "/vehicle/can [can_msgs/msg/Frame]" in " ".join(logged["/discovery/ros2"])
    assert any("vehicle/can/bridges/" in line for line in logged["/discovery/bridges"])
    assert leftovers(run_dir) == []


def test_an_invalid_run_runs_again_and_keeps_every_attempt():
    proc, run_dir = bench_run(DATA / "emulator-never-on-time.yaml", BENCH_RETRY_INVALID="1")
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]
    runs = attempts(proc)
    assert len(runs) == 2 and runs[0] != runs[1], runs
    assert "attempt 1 of 2 was INVALID: EMULATOR" in proc.stderr
    for run in runs:  # each attempt keeps its reports and says why it is no verdict
        assert json.loads((REPO / run / "metrics.json").read_text())["validity"]["outcome"] == "invalid: emulator"
        assert leftovers(REPO / run) == []
    assert "INVALID: EMULATOR, no verdict on the bridge (exit 1)" in proc.stdout.splitlines()[-1]


def test_invalid_scenario_stops_with_exit_2_and_file_line():
    scenario = DATA / "unknown-key.yaml"
    proc, run_dir = bench_run(scenario)
    assert proc.returncode == 2
    # the path as the user gave it, not the container's /scenarios/...
    assert f"{scenario}:9: ecus.0: Additional properties are not allowed ('sped' was unexpected)" in proc.stderr
    assert "/scenarios/" not in proc.stderr
    assert run_dir is None  # nothing ran, no report claims anything


# smoke and ros2-output have tests of their own (every report; the viewer's recording)
SHIPPED = sorted(p for p in (REPO / "scenarios").glob("*.yaml") if p.stem not in ("smoke", "ros2-output"))


@pytest.mark.parametrize("scenario", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_scenario_passes_against_the_real_bridge(scenario):
    proc, run_dir = bench_run(scenario)
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-3000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["passed"] is True
    # every direction the scenario exercises carried frames, and the recording holds them
    assert all(s["matched"] > 0 for s in metrics["can_to_zenoh"].values())
    if "commands:" in scenario.read_text():
        assert metrics["zenoh_to_can"] and all(s["matched"] > 0 for s in metrics["zenoh_to_can"].values())
    assert (run_dir / "report.html").is_file() and (run_dir / "recording.mcap").stat().st_size > 0
    assert leftovers(run_dir) == []
