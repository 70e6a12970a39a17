"""The bench never pulls: with an image missing, bench-run and bench-suite stop (exit 2) naming
it, before any `docker run` or compose call could ask a registry for it."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
# `docker image inspect` answers "no such image"; every call is logged
FAKE_DOCKER = """#!/bin/sh
echo "$*" >>"$FAKE_LOG"
[ "$1" = image ] && exit 1
exit 0
"""


@pytest.mark.parametrize("script", ["bench-run", "bench-suite"])
def test_a_missing_image_stops_the_run_without_a_pull(tmp_path, script):
    bins = tmp_path / "bin"
    bins.mkdir()
    (bins / "docker").write_text(FAKE_DOCKER)
    (bins / "docker").chmod(0o755)
    log = tmp_path / "docker.log"
    env = {**os.environ, "PATH": f"{bins}:{os.environ['PATH']}", "FAKE_LOG": str(log),
           "BENCH_TAG": "0000notbuilt", "COMPOSE": "docker compose"}
    proc = subprocess.run([str(REPO / "scripts" / script), "scenarios/smoke.yaml"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "canbench/orchestrator:0000notbuilt" in proc.stderr
    assert "the bench never pulls" in proc.stderr
    calls = log.read_text().splitlines()
    assert calls and all(c.startswith("image inspect ") for c in calls), calls
