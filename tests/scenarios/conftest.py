"""pytest plugin for bench runs (inside the orchestrator container): options
--scenario/--run-id/--run-dir/--router, the run executed once per session,
verdicts written back into metrics.json."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from canbench import checks, run, scenario


def pytest_addoption(parser):
    group = parser.getgroup("canbench", "CAN <-> Zenoh bench run")
    group.addoption("--scenario", default=os.environ.get("SCENARIO"), help="scenario file to run")
    group.addoption("--run-id", default=os.environ.get("RUN_ID", "local"), help="run identifier")
    group.addoption("--run-dir", default=os.environ.get("RUN_DIR"), help="where the run writes its files")
    group.addoption("--router", default=os.environ.get("BENCH_ROUTER", "tcp/router:7447"),
                    help="Zenoh router endpoint the bench coordinates through")
    group.addoption("--consumer", default=os.environ.get("BENCH_CONSUMER"),
                    help="endpoint the capture and the commands connect to (default: the router)")
    group.addoption("--baseline", default=os.environ.get("BENCH_BASELINE") or None,
                    help="metrics.json (or its run directory) of a run to gate relative regressions against")


@pytest.fixture(scope="session")
def bench_options(request):
    opts = request.config.option
    if not opts.scenario or not opts.run_dir:
        pytest.skip("not a bench run: --scenario and --run-dir are needed (make test runs this in compose)")
    return opts


@pytest.fixture(scope="session")
def scenario_run(bench_options, request):
    sc = scenario.load(bench_options.scenario)
    baseline = None
    if bench_options.baseline:
        path = Path(bench_options.baseline)
        baseline = json.loads((path / "metrics.json" if path.is_dir() else path).read_text())
    result = run.execute(sc, bench_options.run_id, Path(bench_options.run_dir), bench_options.router,
                         consumer=bench_options.consumer, baseline=baseline)
    request.config._bench_result = result
    return result


def pytest_runtest_logreport(report):
    if report.when == "call" or (report.when == "setup" and report.outcome != "passed"):
        verdicts = getattr(pytest, "_bench_verdicts", {})
        verdicts[report.nodeid.split("::")[-1]] = report.outcome
        pytest._bench_verdicts = verdicts


def pytest_sessionfinish(session, exitstatus):
    result = getattr(session.config, "_bench_result", None)
    if result is None:
        return
    result.metrics["verdicts"] = getattr(pytest, "_bench_verdicts", {})
    result.metrics["problems"] = checks.failing(result)
    result.metrics["passed"] = all(v in ("passed", "skipped") for v in result.metrics["verdicts"].values())
    run.write_metrics(result)
