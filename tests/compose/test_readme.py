"""README's scenario-writing block, all of it, as written, in a fresh clone of this checkout:
make summarise/scaffold/validate on a shipped trace, then make test of the scaffolded scenario
in compose and make open. Nothing on the host but what make test needs: no .venv (canbench runs
in the orchestrator image), the images of this checkout (BENCH_TAG, as make check-compose sets
it), no canbench on PATH."""
from __future__ import annotations

import os
import subprocess

import pytest
from readme_blocks import fresh_clone, path_without_canbench, readme_block

pytestmark = pytest.mark.compose

LINE_TIMEOUT_S = 300


def test_scenario_writing_block_in_compose(tmp_path):
    tag = os.environ.get("BENCH_TAG")
    image = f"canbench/orchestrator:{tag}"
    if not tag or subprocess.run(["docker", "image", "inspect", image], capture_output=True).returncode != 0:
        if os.environ.get("BENCH_REQUIRE_IMAGES"):
            pytest.fail(f"{image} does not exist although make built the images")
        pytest.skip("bench images not built (make images; BENCH_TAG names them)")
    clone = fresh_clone(tmp_path)
    env = {**os.environ, "PATH": path_without_canbench(), "BENCH_TAG": tag}
    env.pop("VENV", None)
    out = ""
    for line in readme_block("Writing a scenario"):
        proc = subprocess.run(line, shell=True, cwd=clone, capture_output=True, text=True, timeout=LINE_TIMEOUT_S,
                              env=env)
        assert proc.returncode == 0, f"README line {line!r} failed:\n{proc.stdout}{proc.stderr}"
        out += proc.stdout
    assert "scenarios/my-drive.yaml: ok" in out and "make test: all 1 scenario(s) passed" in out
    assert (clone / "reports" / "latest" / "report.html").is_file()
    assert f"{clone}/reports/latest/report.html" in out  # make open names the page
