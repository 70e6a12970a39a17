"""README stays true: its scenario-writing block runs as written in a fresh clone of this
checkout on a shipped trace (canbench from a stand-in .venv; tests/compose/test_readme.py runs
the whole block, make test included, with the images), and the two commands are make targets
whose set-up installs host packages and .venv/."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
COMPOSE_LINES = ("make test", "make open")  # need the images: tests/compose/test_readme.py


def readme_block(heading: str) -> list[str]:
    """The commands of the first sh block under a README heading, comments stripped."""
    text = (REPO / "README.md").read_text()
    section = text.split(f"\n## {heading}\n", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block, f"README: no sh block under '## {heading}'"
    return [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.split("#", 1)[0].strip()]


def fresh_clone(tmp_path: Path) -> Path:
    """git clone of this checkout, with its uncommitted changes laid over (what is tested is
    what is here), no build products, no .venv, no reports."""
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


def path_without_canbench() -> str:
    """PATH as on a fresh machine: no canbench installed anywhere (it is, here, by pip)."""
    return os.pathsep.join(d for d in os.environ["PATH"].split(os.pathsep) if not (Path(d) / "canbench").exists())


def test_scenario_writing_block_runs_as_written(tmp_path):
    clone = fresh_clone(tmp_path)
    venv = tmp_path / "venv" / "bin"  # stands in for .venv/ (make check's pip install -e .)
    venv.mkdir(parents=True)
    (venv / "canbench").write_text(f"#!/bin/sh\nPYTHONPATH={clone} exec {sys.executable} -m canbench.cli \"$@\"\n")
    (venv / "canbench").chmod(0o755)
    lines = readme_block("Writing a scenario")
    assert any(line.startswith("make test SCENARIO=") for line in lines)
    outputs = []
    for line in lines:
        if line.startswith(COMPOSE_LINES):
            continue
        proc = subprocess.run(line, shell=True, cwd=clone, capture_output=True, text=True, timeout=120,
                              env={**os.environ, "VENV": str(venv.parent), "PATH": path_without_canbench()})
        assert proc.returncode == 0, f"README line {line!r} failed:\n{proc.stdout}{proc.stderr}"
        outputs.append(proc.stdout)
    assert "bus load" in outputs[0]
    assert (clone / "scenarios" / "my-drive.yaml").is_file()
    assert (clone / "scenarios" / "traces" / "drive.log").is_file()
    assert "scenarios/my-drive.yaml: ok" in outputs[-1]


def test_the_two_commands_and_their_set_up(tmp_path):
    assert readme_block("The two commands") == ["make test", "make check"]
    clone = fresh_clone(tmp_path)
    env = {**os.environ, "BENCH_TAG": "readme-test"}  # no image is looked for or built
    # dry runs (CHECK_PHASES emptied: recipes that call $(MAKE) run even under -n)
    for args in (["test"], ["check", "CHECK_PHASES="]):
        proc = subprocess.run(["make", "-n", *args], cwd=clone, capture_output=True, text=True, timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr
    makefile = (clone / "Makefile").read_text()
    phases = re.search(r"^CHECK_PHASES := (.*)$", makefile, re.M).group(1).split()
    assert phases and all(re.search(rf"^{p}:", makefile, re.M) for p in phases)
    setup = subprocess.run(["make", "-n", "setup"], cwd=clone, capture_output=True, text=True, timeout=120).stdout
    assert "scripts/host-deps \"make check\"" in setup and "python3 -m venv .venv" in setup
    assert "pip install" in setup and "-e '.[test,viewer]'" in setup
