"""make summarise / scaffold / validate pass the user's paths to canbench as the user named them:
a path with a space or a quote is one argument (it was split at the space), while a list of
files (validate's default, every scenario; several traces) stays a list. canbench is a stand-in
that prints the arguments it got (the Makefile takes $(VENV)/bin/canbench when it exists)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
MAKEFILE = REPO / "Makefile"


@pytest.fixture
def make(tmp_path):
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    stand_in = venv / "bin" / "canbench"
    stand_in.write_text(f"#!{sys.executable}\nimport json, sys\nprint(json.dumps(sys.argv[1:]))\n")
    stand_in.chmod(0o755)
    # what the Makefile would otherwise ask git, docker and the host for: not needed here
    env = {**os.environ, "BENCH_TAG": "make-paths-test", "RUST_PORT": "copy", "COMPOSE": "docker compose",
           "BENCH_CAN_MODE": "userspace"}

    def run(target: str, **variables: str) -> list[str]:
        args = ["make", "-s", "-f", str(MAKEFILE), "-C", str(REPO), target, f"VENV={venv}",
                *(f"{k}={v}" for k, v in variables.items())]
        proc = subprocess.run(args, capture_output=True, text=True, timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)
    return run


def files(tmp_path: Path, *names: str) -> list[str]:
    for name in names:
        (tmp_path / name).write_text("")
    return [str(tmp_path / name) for name in names]


def test_summarise_takes_a_trace_with_a_space_or_a_quote_as_one(make, tmp_path):
    spaced, quoted, dbc = files(tmp_path, "a b.log", "it's.log", "my db.dbc")
    assert make("summarise", TRACE=spaced) == ["summarise", spaced]  # was [..., '.../a', 'b.log']
    assert make("summarise", TRACE=quoted, DBC=dbc) == ["summarise", quoted, "--dbc", dbc]
    one, two = files(tmp_path, "one.log", "two.log")
    assert make("summarise", TRACE=f"{one} {two}") == ["summarise", one, two]


def test_scaffold_quotes_its_trace_name_and_dbc(make, tmp_path):
    spaced, dbc = files(tmp_path, "a b.log", "my db.dbc")
    assert make("scaffold", TRACE=spaced, NAME="drive", DBC=dbc) == \
        ["scaffold", spaced, "--name", "drive", "--dbc", dbc]
    assert make("scaffold", TRACE=spaced, NAME="my drive") == ["scaffold", spaced, "--name", "my drive"]


def test_validate_takes_one_scenario_with_a_space_or_a_list(make, tmp_path):
    [spaced] = files(tmp_path, "my drive.yaml")
    assert make("validate", SCENARIO=spaced) == ["validate", spaced]
    one, two = files(tmp_path, "one.yaml", "two.yaml")
    assert make("validate", SCENARIO=f"{one} {two}") == ["validate", one, two]
    shipped = make("validate")  # the default: every shipped scenario
    assert len(shipped) > 2 and "scenarios/smoke.yaml" in shipped
