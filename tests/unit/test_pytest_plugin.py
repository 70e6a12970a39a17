"""The bench-run pytest plugin (canbench.pytest_plugin, loaded by its pytest11 entry point): inert
without a run's options, and on a run it records each check's verdict, writes them into
metrics.json and writes the reports."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from synthetic import synthetic_run

from canbench import checks, run

pytestmark = pytest.mark.unit
pytest_plugins = ["pytester"]
REPO = Path(__file__).resolve().parents[2]


def test_without_a_run_every_check_skips_and_nothing_is_written(pytester, monkeypatch):
    for var in ("SCENARIO", "RUN_DIR"):
        monkeypatch.delenv(var, raising=False)
    outcome = pytester.runpytest_inprocess("-p", "no:cacheprovider", "--pyargs", "canbench.scenario_checks")
    outcome.assert_outcomes(skipped=len(checks.CHECKS))
    assert not list(pytester.path.iterdir())


def test_a_run_records_verdicts_into_metrics_and_writes_reports(pytester, monkeypatch, tmp_path):
    executed = []

    def execute(sc, run_id, run_dir, router, **kw):
        executed.append((sc.name, run_id, router))
        return synthetic_run(run_dir)
    monkeypatch.setattr(run, "execute", execute)
    scenario_file = REPO / "scenarios" / "smoke.yaml"
    outcome = pytester.runpytest_inprocess("-p", "no:cacheprovider", "--pyargs", "canbench.scenario_checks",
                                           f"--scenario={scenario_file}", f"--run-dir={tmp_path}", "--run-id=r1")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert executed == [("smoke", "r1", "tcp/127.0.0.1:7447")]  # once per session; loopback unless told
    assert metrics["verdicts"]["test_check[integrity]"] == "failed"
    assert metrics["passed"] is False and "1 frames lost" in json.dumps(metrics["problems"])
    failed = [name for name, v in metrics["verdicts"].items() if v == "failed"]
    outcome.assert_outcomes(failed=len(failed), passed=sum(v == "passed" for v in metrics["verdicts"].values()),
                            skipped=sum(v == "skipped" for v in metrics["verdicts"].values()))
    assert (tmp_path / "report.html").exists() and (tmp_path / "recording.mcap").exists()
