"""The pytest plugin of a bench run (entry point pytest11 "canbench"; the orchestrator runs
`pytest --pyargs canbench.scenario_checks`): options --scenario/--run-id/--run-dir/--router/...,
the run executed once per session (the scenario_run fixture), verdicts written back into
metrics.json, then recording.mcap and report.html. Inert in any other pytest run: without
--scenario and --run-dir the fixture skips, and no result means nothing is written."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

from . import analysis, checks, dbc, recording, report, run, scenario

PLUGIN_NAME = "canbench-run"


def pytest_addoption(parser):
    group = parser.getgroup("canbench", "CAN <-> Zenoh bench run")
    group.addoption("--scenario", default=os.environ.get("SCENARIO"), help="scenario file to run")
    group.addoption("--run-id", default=os.environ.get("RUN_ID", "local"), help="run identifier")
    group.addoption("--run-dir", default=os.environ.get("RUN_DIR"), help="where the run writes its files")
    group.addoption("--router", default=os.environ.get("BENCH_ROUTER", "tcp/127.0.0.1:7447"),  # compose sets it
                    help="Zenoh router endpoint the bench coordinates through")
    group.addoption("--consumer", default=os.environ.get("BENCH_CONSUMER"),
                    help="endpoint the capture and the commands connect to (default: the router)")
    group.addoption("--project", default=os.environ.get("BENCH_PROJECT") or None,
                    help="the run's compose project (fault steps act on its containers)")
    group.addoption("--viewer", action="store_true", default=bool(os.environ.get("BENCH_VIEWER")),
                    help="a viewer records the run (traffic.rrd): wait for it before the traffic starts")
    group.addoption("--baseline", default=os.environ.get("BENCH_BASELINE") or None,
                    help="metrics.json (or its run directory) of a run to gate relative regressions against")
    group.addoption("--device", default=os.environ.get("BENCH_DEVICE") or None,
                    help="a device of your own in the bridge's place (DEVICE=host:PORT), as metrics.json records it")
    group.addoption("--device-announces", choices=("0", "1"),
                    default=os.environ.get("BENCH_DEVICE_ANNOUNCES") or "1",  # checked by the run, as given
                    help="0: the device declares neither the bridge's liveliness token nor its stats queryable "
                         "(DEVICE_ANNOUNCES=0): ready once it subscribes to the tx keys")
    group.addoption("--ready-timeout", type=float, default=float(os.environ.get("BENCH_READY_TIMEOUT_S") or
                                                                 run.BRIDGE_READY_TIMEOUT_S),
                    help="seconds to wait for the bridge's (or the device's) liveliness token, or the subscription "
                         "of a device that announces nothing")


def _announces(value: str) -> bool:
    """--device-announces as given (an environment default escapes argparse's choices)."""
    if value not in ("0", "1"):
        raise pytest.UsageError(f"--device-announces / BENCH_DEVICE_ANNOUNCES={value!r}: expected 0 or 1")
    return value == "1"


def pytest_configure(config):
    config.pluginmanager.register(BenchRun(), PLUGIN_NAME)


@pytest.fixture(scope="session")
def bench_options(request):
    opts = request.config.option
    if not opts.scenario or not opts.run_dir:
        pytest.skip("not a bench run: --scenario and --run-dir are needed (make test runs this in compose)")
    return opts


@pytest.fixture(scope="session")
def scenario_run(bench_options, request):
    """The run, executed once per session; the plugin object keeps it for the session's end."""
    sc = scenario.load(bench_options.scenario)
    baseline = None
    if bench_options.baseline:
        path = Path(bench_options.baseline)
        baseline = json.loads((path / "metrics.json" if path.is_dir() else path).read_text())
    result = run.execute(sc, bench_options.run_id, Path(bench_options.run_dir), bench_options.router,
                         consumer=bench_options.consumer, baseline=baseline, project=bench_options.project,
                         wait_viewer=bench_options.viewer, ready_timeout_s=bench_options.ready_timeout,
                         device=bench_options.device, device_announces=_announces(bench_options.device_announces))
    request.config.pluginmanager.get_plugin(PLUGIN_NAME).result = result
    return result


def write_reports(result: analysis.RunResult) -> list[str]:
    """recording.mcap and report.html after the verdicts they show; the failures, never raised
    (a report writer must not change a verdict)."""
    writers = {"recording.mcap": lambda p: recording.write_mcap(result, p, dbc.load_dbc(result.scenario.dbc)),
               "report.html": lambda p: report.write_html(result, p)}
    failed = []
    for name, write in writers.items():
        try:
            write(result.run_dir / name)
        except Exception as e:  # noqa: BLE001 - any failure of a report writer is reported the same way
            failed.append(f"writing {name} failed: {e!r}")
    return failed


class BenchRun:
    """The session's run result and the verdict of each check, as pytest reports them."""

    def __init__(self) -> None:
        self.result: analysis.RunResult | None = None
        self.verdicts: dict[str, str] = {}

    def pytest_runtest_logreport(self, report):
        if report.when == "call" or (report.when == "setup" and report.outcome != "passed"):
            self.verdicts[report.nodeid.split("::")[-1]] = report.outcome

    def pytest_sessionfinish(self, session, exitstatus):
        result = self.result
        if result is None:
            return
        result.metrics["verdicts"] = dict(self.verdicts)
        result.metrics["problems"] = checks.failing(result)
        result.metrics["passed"] = all(v in ("passed", "skipped") for v in result.metrics["verdicts"].values())
        analysis.write_metrics(result)
        for problem in write_reports(result):
            print(f"\ncanbench: {problem}", file=sys.stderr)
            session.exitstatus = session.exitstatus or 1

    def pytest_terminal_summary(self, terminalreporter, exitstatus, config):
        result = self.result
        if result is None:
            return
        tr = terminalreporter
        tr.section(f"bench run {result.run_id}")
        directions = {"can_to_zenoh": "CAN -> Zenoh", "zenoh_to_can": "Zenoh -> CAN", "round_trip": "round trip"}
        for key, label in directions.items():
            for bus, s in result.metrics.get(key, {}).items():
                lat = s["latency"]
                p50 = "-" if lat["p50_ms"] is None else f"{lat['p50_ms']:.3f}"
                p99 = "-" if lat["p99_ms"] is None else f"{lat['p99_ms']:.3f}"
                low = "-" if lat.get("min_ms") is None else f"{lat['min_ms']:.3f}"
                tr.write_line(f"{label:13} {bus:6} {s['matched']:>7}/{s['sent']:<7} matched  lost {s['lost']:<5} "
                              f"dup {s['duplicates']:<4} corrupt {s['corrupted']:<4} reorder {s['reordered']:<4} "
                              f"min {low} ms  p50 {p50} ms  p99 {p99} ms")
        outcome = (result.metrics.get("validity") or {}).get("outcome", "valid")
        if outcome != "valid":  # the bench spoilt the run: said first, and that the bridge was not judged
            tr.write_line(f"{outcome.upper()}: no verdict on the bridge (valid_run says why)", red=True, bold=True)
        tr.write_line(f"report: {result.run_dir / 'report.html'}")
