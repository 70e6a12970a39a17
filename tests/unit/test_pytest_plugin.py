"""The bench-run pytest plugin (canbench.pytest_plugin, loaded by its pytest11 entry point): inert
without a run's options, and on a run it records each check's verdict, writes them into
metrics.json and writes the reports."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from canbench import analysis, checks, oracle, run, scenario, wire

pytestmark = pytest.mark.unit
pytest_plugins = ["pytester"]
REPO = Path(__file__).resolve().parents[2]


def synthetic_run(run_dir: Path, lose: int | None) -> analysis.RunResult:
    """smoke.yaml's bus trace as captured, and the Zenoh side without frame `lose`."""
    sc = scenario.load(REPO / "scenarios" / "smoke.yaml")
    (run_dir / "can.log").write_text((REPO / "scenarios" / "traces" / "powertrain-2s.log").read_text())
    with open(run_dir / "zenoh.tsv", "w") as f:
        for i, o in enumerate(oracle.read_candump(run_dir / "can.log", "vcan0")):
            if i != lose:
                f.write(f"{o.t_ns + 400_000}\tvehicle/can/rx\t{wire.encode(o.frame).hex()}\t"
                        f"{wire.encode_attachment(i, [o.t_ns]).hex()}\n")
    return analysis.analyse(sc, "synthetic", run_dir, "vehicle/can", {}, None, 2.0)


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
        return synthetic_run(run_dir, lose=50)
    monkeypatch.setattr(run, "execute", execute)
    scenario_file = REPO / "scenarios" / "smoke.yaml"
    outcome = pytester.runpytest_inprocess("-p", "no:cacheprovider", "--pyargs", "canbench.scenario_checks",
                                           f"--scenario={scenario_file}", f"--run-dir={tmp_path}", "--run-id=r1")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert executed == [("smoke", "r1", "tcp/router:7447")]  # once per session
    assert metrics["verdicts"]["test_check[integrity]"] == "failed"
    assert metrics["passed"] is False and "1 frames lost" in json.dumps(metrics["problems"])
    failed = [name for name, v in metrics["verdicts"].items() if v == "failed"]
    outcome.assert_outcomes(failed=len(failed), passed=sum(v == "passed" for v in metrics["verdicts"].values()),
                            skipped=sum(v == "skipped" for v in metrics["verdicts"].values()))
    assert (tmp_path / "report.html").exists() and (tmp_path / "recording.mcap").exists()
