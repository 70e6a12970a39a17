"""README stays true: its scenario-writing block runs as written in a fresh clone of this
checkout on a shipped trace (canbench from a stand-in .venv; tests/compose/test_readme.py runs
the whole block, make test included, with the images), and the two commands are make targets
whose set-up installs host packages and .venv/."""
from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from readme_blocks import fresh_clone, path_without_canbench, readme_block

pytestmark = pytest.mark.unit

COMPOSE_LINES = ("make test", "make open")  # need the images: tests/compose/test_readme.py


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
