"""One run of a scenario against a seeded-fault bridge, as compose runs it: zenoh-node-faulty
(ZN_FAULT=fault) on the host bus for the scenario's buses, its ECUs as `canbench ecu`
processes, the checks as pytest --pyargs canbench.scenario_checks. Shared by
test_seeded_faults.py and test_real_traces.py, which judge what the run's checks said."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from conftest import REPO, Bridge, zenoh_session

from canbench import scenario

RUN_TIMEOUT_S = 120
# an invalid run (an ECU behind its trace on a loaded machine, a capture that dropped) is no verdict:
# run again, as scripts/bench-run does (its BENCH_RETRY_INVALID default)
INVALID_RETRIES = 2


@dataclass
class FaultRun:
    metrics: dict                              # the run's metrics.json
    orchestrator: subprocess.CompletedProcess  # the checks' pytest: exit 0 when every check passed
    run_dir: Path

    @property
    def failed(self) -> set[str]:
        """The names of the checks that failed (verdicts are keyed test_check[name])."""
        return {check.split("[")[1].rstrip("]") for check, outcome in self.metrics["verdicts"].items()
                if outcome == "failed"}


def run_case(bus, router, tmp_path: Path, bridge_binary: Path, scenario_path: Path, fault: str, run_id: str,
             options: tuple[str, ...] = ()) -> FaultRun:
    """Runs scenario_path with the bridge started with ZN_FAULT=fault and extra bridge options;
    every ECU must exit 0, the checks may fail (that is what the caller judges). An invalid run
    runs again (a new bridge, run directory and run id), up to INVALID_RETRIES times."""
    for attempt in range(INVALID_RETRIES + 1):
        suffix = f"-{attempt + 1}" if attempt else ""
        run = _run_once(bus, router, tmp_path / f"run{suffix}", bridge_binary, scenario_path, fault,
                        run_id + suffix, options)
        outcome = run.metrics.get("validity", {}).get("outcome", "valid")
        if not outcome.startswith("invalid"):
            break
        print(f"attempt {attempt + 1} was {outcome}: {run.metrics['validity']['problems']}")
    return run


def _run_once(bus, router, run_dir: Path, bridge_binary: Path, scenario_path: Path, fault: str, run_id: str,
              options: tuple[str, ...]) -> FaultRun:
    sc = scenario.load(scenario_path)
    bridge = Bridge(bus, router)
    bridge.binary = bridge_binary
    bus.env["ZN_FAULT"] = fault
    bus.env["PATH"] = f"{bus.tool('')}:{bus.env['PATH']}"  # ucanctl for the capture's readiness check
    ecus = []
    try:
        bridge.start("--can", ",".join(sc.bus_names), "--publish-period-ms", str(sc.bridge.get("publish_period_ms", 0)),
                     "--tx-max-age-ms", str(sc.tx_max_age_ms), *options)
        session = zenoh_session(router.endpoint)
        bridge.wait_ready(session)
        session.close()
        common = ["--scenario", str(scenario_path), "--run-id", run_id, "--run-dir", str(run_dir),
                  "--router", router.endpoint]
        ecus = [bus.popen([sys.executable, "-m", "canbench.cli", "ecu", "--name", e.name, *common])
                for e in sc.ecus]
        orchestrator = bus.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                "--pyargs", "canbench.scenario_checks", *common], check=False,
                               timeout=RUN_TIMEOUT_S, cwd=REPO)
        for ecu in ecus:
            assert ecu.wait(timeout=RUN_TIMEOUT_S) == 0, ecu.stderr.read()
        return FaultRun(json.loads((run_dir / "metrics.json").read_text()), orchestrator, run_dir)
    finally:
        for ecu in ecus:
            if ecu.poll() is None:
                ecu.kill()
        if bridge.proc and bridge.proc.poll() is None:
            bridge.stop()
        print(bridge.log.read_text()[-3000:] if bridge.log.exists() else "")  # shown when the test fails
