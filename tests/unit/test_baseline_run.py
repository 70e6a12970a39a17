"""scripts/baseline-run, bench-run's choice of the run a scenario's latency is compared with: the
newest passed run of exactly that scenario (smoke's baseline is never a run of can-fd-smoke or
beef-smoke, whose run ids also end in -smoke), nothing for a scenario with no passed run yet (it
then runs without a baseline), and a file or run directory given as it is."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit
SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "baseline-run"


def baseline(base: Path | str, name: str, device: str = "") -> str:
    env = {**os.environ, "DEVICE": device}
    return subprocess.run([str(SCRIPT), str(base), name], capture_output=True, text=True, check=True,
                          env=env).stdout.strip()


def run(reports: Path, run_id: str, passed: bool, device: str | None = None) -> Path:
    (reports / run_id).mkdir(parents=True)
    said = f',\n  "device": "{device}"' if device else ',\n  "device": null'
    (reports / run_id / "metrics.json").write_text(f'{{\n  "passed": {str(passed).lower()}{said}\n}}\n')
    return reports / run_id / "metrics.json"


def test_the_newest_passed_run_of_exactly_that_scenario(tmp_path):
    good = run(tmp_path, "20260101-010000-000-abcd-smoke", True)
    run(tmp_path, "20260102-010000-000-abcd-smoke", False)
    run(tmp_path, "20260103-010000-000-ef01-can-fd-smoke", True)
    run(tmp_path, "20260104-010000-000-ef01-beef-smoke", True)
    assert baseline(tmp_path, "smoke") == str(good)
    assert baseline(tmp_path, "beef-smoke") == str(tmp_path / "20260104-010000-000-ef01-beef-smoke" / "metrics.json")


def test_a_scenario_without_a_passed_run_has_none(tmp_path):
    run(tmp_path, "20260101-010000-000-abcd-smoke", True)
    assert baseline(tmp_path, "new-scenario") == ""


def test_a_run_or_its_metrics_is_taken_as_given(tmp_path):
    metrics = run(tmp_path, "20260101-010000-000-abcd-smoke", False)
    assert baseline(metrics.parent, "other") == str(metrics)
    assert baseline(metrics, "other") == str(metrics)
    assert baseline(tmp_path / "missing.json", "smoke") == str(tmp_path / "missing.json")


def test_a_device_of_your_own_and_the_benchs_bridge_are_each_others_baseline_never(tmp_path):
    bridge = run(tmp_path, "20260101-010000-000-abcd-smoke", True)
    gateway = run(tmp_path, "20260102-010000-000-abcd-smoke", True, device="host:7448")
    assert baseline(tmp_path, "smoke") == str(bridge)
    assert baseline(tmp_path, "smoke", device="host:7449") == str(gateway)
