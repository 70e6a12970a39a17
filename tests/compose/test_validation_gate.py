"""make test validates every scenario and its traces before anything starts: a malformed
trace line (`16G#D032`, 9 data bytes) stops it with exit code 2 and every problem as
file:line, with the paths as the user wrote them (not the containers' /scenarios/...), and
no compose project is started (the compose command is replaced by one that records calls)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.compose

REPO = Path(__file__).resolve().parents[2]

SCENARIO = """name: bad-trace
duration_s: 5
buses: [{name: vcan0}]
ecus:
  - name: engine
    bus: vcan0
    trace: traces/t.log
expect: {integrity: true}
"""
TRACE = ("(1700000000.000000) vcan0 123#DEADBEEF\n"
         "(1700000000.001000) vcan0 16G#D032\n"
         "(1700000000.002000) vcan0 125#000102030405060708\n")


def test_bad_trace_stops_make_test_before_compose(tmp_path):
    tag = os.environ.get("BENCH_TAG")
    if not tag or subprocess.run(["docker", "image", "inspect", f"canbench/orchestrator:{tag}"],
                                 capture_output=True).returncode != 0:
        if os.environ.get("BENCH_REQUIRE_IMAGES"):
            pytest.fail(f"canbench/orchestrator:{tag} does not exist although make built the images")
        pytest.skip("bench images not built (make images; BENCH_TAG names them)")
    (tmp_path / "traces").mkdir()
    (tmp_path / "traces" / "t.log").write_text(TRACE)
    (tmp_path / "bad.yaml").write_text(SCENARIO)
    spy = tmp_path / "compose-calls"
    compose = tmp_path / "compose"
    # `version` answered for make's preflight; anything else would start a project: recorded
    compose.write_text(f"#!/bin/sh\n[ \"$1\" = version ] && exit 0\necho \"$@\" >>{spy}\nexit 1\n")
    compose.chmod(0o755)
    given = os.path.relpath(tmp_path / "bad.yaml", REPO)  # as a user in the checkout would write it
    before = set((REPO / "reports").glob("suite-*"))
    proc = subprocess.run(["make", "--no-print-directory", "test", f"SCENARIO={given}", f"COMPOSE={compose}"],
                          cwd=REPO, capture_output=True, text=True, timeout=300, env={**os.environ, "BENCH_TAG": tag})
    assert proc.returncode == 2, proc.stdout + proc.stderr
    trace = os.path.join(os.path.dirname(given), "traces", "t.log")
    assert f"{trace}:2: not a candump -L frame" in proc.stderr, proc.stderr
    assert f"{trace}:3: 9 data bytes: classic CAN carries at most 8" in proc.stderr
    assert "/scenarios/" not in proc.stderr
    assert not spy.exists()  # compose never called: nothing started
    assert set((REPO / "reports").glob("suite-*")) == before
