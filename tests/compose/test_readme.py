"""README's scenario-writing block, all of it, as written, in a fresh clone of this checkout:
make summarise/scaffold/validate on a shipped trace, then make test of the scaffolded scenario
in compose and make open. Nothing on the host but what make test needs: no .venv (canbench runs
in the orchestrator image), the images of this checkout (BENCH_TAG, as make check-compose sets
it), no canbench on PATH."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.compose

REPO = Path(__file__).resolve().parents[2]
LINE_TIMEOUT_S = 300


def readme_block(heading: str) -> list[str]:
    section = (REPO / "README.md").read_text().split(f"\n## {heading}\n", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block, f"README: no sh block under '## {heading}'"
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.split("#", 1)[0].strip()]


def fresh_clone(tmp_path: Path) -> Path:
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True, timeout=120)
    changed = subprocess.run(["git", "ls-files", "-m", "-o", "--exclude-standard"], cwd=REPO, check=True,
                             capture_output=True, text=True).stdout.split()
    for name in changed:
        if (REPO / name).is_file():
            (clone / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, clone / name)
        elif (clone / name).exists():
            (clone / name).unlink()
    shutil.copy(REPO / "scenarios" / "traces" / "powertrain-2s.log", clone / "drive.log")
    return clone


def test_scenario_writing_block_in_compose(tmp_path):
    tag = os.environ.get("BENCH_TAG")
    image = f"canbench/orchestrator:{tag}"
    if not tag or subprocess.run(["docker", "image", "inspect", image], capture_output=True).returncode != 0:
        if os.environ.get("BENCH_REQUIRE_IMAGES"):
            pytest.fail(f"{image} does not exist although make built the images")
        pytest.skip("bench images not built (make images; BENCH_TAG names them)")
    clone = fresh_clone(tmp_path)
    path = os.pathsep.join(d for d in os.environ["PATH"].split(os.pathsep) if not (Path(d) / "canbench").exists())
    env = {**os.environ, "PATH": path, "BENCH_TAG": tag}
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
