"""A device of your own in the bridge's place, as `make test DEVICE=host:PORT DEVICE_CMD=...`
runs it (scripts/bench-run, canbench.device): the host's own build of zenoh-node, started by
the bench on the host with the run's identity, reaches the router on 127.0.0.1 only and the bus
through the hub's socket directory, and passes the smoke scenario on every check, its own stats
included; the same device with a seeded fault (zenoh-node-faulty) fails the check for that
fault; a device that stops early fails the run; nothing is left behind (containers, the host's
socket directory, the device's processes, a stray child of it included). Needs the images,
`make ucan firmware` and Docker."""
from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_compose import REPO, attempts, bench_run, junit_cases, leftovers

pytestmark = pytest.mark.compose

FIRMWARE = Path(os.environ.get("ZN_BRIDGE", REPO / "build" / "firmware" / "zenoh-node")).parent
PRELOAD = REPO / "build" / "ucan" / "libucan-preload.so"
SMOKE = REPO / "scenarios" / "smoke.yaml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def built():
    missing = [p for p in (FIRMWARE / "zenoh-node", FIRMWARE / "zenoh-node-faulty", PRELOAD) if not p.exists()]
    if missing:
        if os.environ.get("BENCH_REQUIRE_IMAGES"):
            pytest.fail(f"{missing} not built although make built them first")
        pytest.skip(f"host builds missing: {missing} (make ucan firmware)")


def run_device(command: str, scenario: Path = SMOKE, **env: str) -> tuple[subprocess.CompletedProcess, Path, str]:
    device = f"host:{free_port()}"
    proc, run_dir = bench_run(scenario, DEVICE=device, DEVICE_CMD=command, BENCH_RETRY_INVALID="0", **env)
    assert run_dir is not None, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc, run_dir, device


def group_members(pgid: int) -> list[int]:
    """The processes of a process group still alive (field 5 of /proc/<pid>/stat, after the name)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(int(stat.parent.name))
    return out


def nothing_left(proc: subprocess.CompletedProcess, run_dir: Path) -> None:
    assert leftovers(run_dir) == []
    # the device's process group is gone, and so is the host's socket directory
    started = re.search(r"\(pid (\d+); .*; the bus's sockets: (\S+)\)", proc.stdout)
    assert started, proc.stdout
    assert group_members(int(started.group(1))) == []
    assert not Path(started.group(2)).exists()

def test_the_hosts_own_bridge_build_as_a_device_passes_smoke_on_every_check(built):
    proc, run_dir, device = run_device(str(FIRMWARE / "zenoh-node"))
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["device"] == device and metrics["passed"] is True
    assert metrics["can_to_zenoh"]["vcan0"]["matched"] == metrics["ecus"]["engine"]["sent"] > 0
    cases = junit_cases(run_dir)
    for check in ("integrity", "ordering", "latency_can_to_zenoh", "cycle_time", "bridge_stats_agree"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    # the device ran on the host (its log is the run's), the bench's bridge never started
    assert "zenoh-node" in (run_dir / "device.log").read_text()
    assert 'href="device.log"' in (run_dir / "report.html").read_text()  # the report links the device's output
    assert "bridge_1 " not in (run_dir / "containers.log").read_text()
    assert "bridge-1 " not in (run_dir / "containers.log").read_text()
    nothing_left(proc, run_dir)


def test_a_device_with_a_seeded_fault_fails_the_check_for_it(built):
    proc, run_dir, _ = run_device(f"ZN_FAULT=drop:5 exec {FIRMWARE / 'zenoh-node-faulty'}")
    assert proc.returncode == 1, proc.stdout[-4000:] + proc.stderr[-4000:]
    cases = junit_cases(run_dir)
    assert cases["test_check[integrity]"] == "failed", cases
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["can_to_zenoh"]["vcan0"]["lost"] > 0
    nothing_left(proc, run_dir)


def test_a_device_that_stops_before_the_run_ends_fails_it_and_its_stray_child_is_stopped(built):
    # the device's leader exits at once, leaving a child that ignores TERM in its group; the run
    # stops then, not after the 300 s it would wait for the device's token
    started = time.monotonic()
    proc, run_dir, _ = run_device("(trap '' TERM; exec sleep 600) & exit 3", BENCH_READY_TIMEOUT_S="300",
                                  DEVICE_STOP_S="1")
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "the device exited with 3 before the run ended" in proc.stdout
    assert time.monotonic() - started < 200
    nothing_left(proc, run_dir)


def faults_pass(name: str) -> tuple[subprocess.CompletedProcess, Path, dict[str, str]]:
    """The host's zenoh-node as the device through a shipped fault scenario: passed, the faults'
    checks and the stats' included."""
    proc, run_dir, _ = run_device(str(FIRMWARE / "zenoh-node"), REPO / "scenarios" / name)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    cases = junit_cases(run_dir)
    for check in ("faults_injected", "recovery", "integrity", "bridge_stats_agree"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    return proc, run_dir, cases


def test_the_routers_faults_run_against_a_device_and_its_memory_is_not_judged(built):
    # the device reconnects through the port published for it; what only the bench's own bridge
    # container shows (memory, descriptors) is skipped with the reason, never passed
    proc, run_dir, cases = faults_pass("router-faults.yaml")
    assert cases["test_check[bridge_memory]"] == "skipped"
    assert "not a device of your own" in (run_dir / "junit.xml").read_text()
    assert "reconnected to the Zenoh router" in (run_dir / "device.log").read_text()
    nothing_left(proc, run_dir)


def test_a_device_that_announces_nothing_is_ready_by_its_subscription_and_passes_a_round_trip(built):
    # a user's bridge that speaks only the wire format on the rx/tx keys (python-can + zenoh, no
    # liveliness token, no stats queryable): ready once it subscribes to the tx key, drained on the
    # capture, bridge_stats_agree skipped with the reason; every other check judged
    command = (f'PYTHONPATH={REPO} exec {sys.executable} -m bench.refbridge --router "$ZENOH_ROUTER_ADDRESS" '
               f'--can "$ZENOH_NODE_CAN" --no-token')
    proc, run_dir, device = run_device(command, REPO / "scenarios" / "round-trip.yaml", DEVICE_ANNOUNCES="0")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["device"] == device and metrics["device_announces"] is False and metrics["passed"] is True
    assert metrics["bridge_stats"] is None
    cases = junit_cases(run_dir)
    for check in ("integrity", "ordering", "zenoh_to_can", "round_trip", "latency_round_trip"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    assert cases["test_check[bridge_stats_agree]"] == "skipped"
    assert "has no stats queryable (DEVICE_ANNOUNCES=0)" in (run_dir / "junit.xml").read_text()
    assert "(announces nothing: no token, no stats)" in (run_dir / "report.html").read_text()
    nothing_left(proc, run_dir)


def test_a_device_that_announces_nothing_and_subscribes_to_nothing_is_never_ready(built):
    # the same bridge with its command side missing would be waited for until the ready timeout,
    # then the run is an error that names the key, not a verdict
    command = f'exec {sys.executable} -c "import time; time.sleep(600)"'
    proc, run_dir, _ = run_device(command, DEVICE_ANNOUNCES="0", BENCH_READY_TIMEOUT_S="5")
    assert proc.returncode != 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    said = (run_dir / "containers.log").read_text() + (run_dir / "junit.xml").read_text()
    assert "no subscriber on vehicle/can/tx after 5 s: a device that announces nothing" in said
    nothing_left(proc, run_dir)


def test_the_bridges_stop_and_kill_restart_a_device_the_bench_started(built):
    # bench-run stops the device's process group (TERM, or KILL) and runs DEVICE_CMD again after the
    # step's hold; the device comes back on its own, and every check is judged as for the bench's bridge
    proc, run_dir, _ = run_device(str(FIRMWARE / "zenoh-node"), REPO / "scenarios" / "bridge-faults.yaml")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    cases = junit_cases(run_dir)
    for check in ("faults_injected", "recovery", "integrity", "ordering", "zenoh_to_can", "bridge_stats_agree"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    windows = json.loads((run_dir / "metrics.json").read_text())["faults"]["windows"]
    stops = [w for w in windows if w["action"].startswith("bridge_")]
    assert [w["action"] for w in stops] == ["bridge_term", "bridge_kill"]
    assert all(not w["error"] and w["end_ns"] - w["start_ns"] >= 0.5e9 for w in stops), stops  # the hold's 0.5 s
    restarts = re.findall(r"device: (bridge_\w+) at \S+, started again \(pid (\d+)\)", proc.stderr)
    assert [action for action, _ in restarts] == ["bridge_term", "bridge_kill"], proc.stderr[-3000:]
    log = (run_dir / "device.log").read_text()
    assert log.count("ready: zid") == 3, log[-3000:]  # the first start and two more
    assert log.count("final stats") == 2  # TERM lets it say goodbye (and the run's end), KILL does not
    for _, pid in restarts:
        assert group_members(int(pid)) == []
    nothing_left(proc, run_dir)
    assert not list(run_dir.glob("device.re*"))  # the FIFOs are the run's, not reports


def test_a_device_that_does_not_come_back_after_a_stop_fails_the_run(built):
    # DEVICE_CMD run again is the command itself: one that cannot start a second time is a verdict on
    # the device, said as such, never a hang or a pass
    marker = REPO / "build" / f"device-started-{os.getpid()}"
    marker.unlink(missing_ok=True)
    command = f'[ ! -e {marker} ] || exit 7; touch {marker}; exec {FIRMWARE / "zenoh-node"}'
    try:
        proc, run_dir, _ = run_device(command, REPO / "scenarios" / "bridge-faults.yaml")
    finally:
        marker.unlink(missing_ok=True)
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "the device exited with 7 before the run ended" in proc.stdout
    nothing_left(proc, run_dir)


def test_a_partition_cuts_a_devices_link_and_it_reconnects(built):
    # the device is published to the router's listener that the partition drops: its session is cut
    # (it says so when it reconnects), the captures' are not
    proc, run_dir, _ = faults_pass("network-partition.yaml")
    assert "reconnected to the Zenoh router" in (run_dir / "device.log").read_text()
    nothing_left(proc, run_dir)


def test_the_bridges_stop_and_kill_call_the_hook_of_a_device_the_bench_does_not_start(built, tmp_path):
    # a device started by hand (as a board would be powered up) with DEVICE_HOOK: bench-run calls the
    # hook to stop it and, after the step's hold, to start it again; here the hook is a power relay's
    # stand-in that signals the host's zenoh-node and runs it again with what bench-run tells it
    (tmp_path / "hook.sh").write_text(f"""#!/usr/bin/env bash
set -eu
cd {tmp_path}
echo "$1 $2" >>calls
if [ "$1" = stop ]; then
	pid=$(cat pid)
	kill -$([ "$2" = bridge_kill ] && echo KILL || echo TERM) -- -"$pid"
	exec timeout 10 tail -s 0.05 --pid="$pid" -f /dev/null  # until it exited (a relay: until the power is off)
fi
set -a; . "$DEVICE_ENV_FILE"; set +a
ZENOH_CONFIG=$DEVICE_ZENOH_CONFIG ZENOH_ROUTER_ADDRESS=$DEVICE_ROUTER_ADDRESS UCAN_DIR=$DEVICE_UCAN_DIR \\
	LD_PRELOAD=$DEVICE_PRELOAD setsid {FIRMWARE / 'zenoh-node'} >>device.out 2>&1 </dev/null &
echo $! >pid
""")
    (tmp_path / "hook.sh").chmod(0o755)
    proc = subprocess.Popen([str(REPO / "scripts" / "bench-run"), str(REPO / "scenarios" / "bridge-faults.yaml")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                            env={**os.environ, "DEVICE": f"host:{free_port()}",
                                 "DEVICE_HOOK": str(tmp_path / "hook.sh"), "BENCH_READY_TIMEOUT_S": "120"})
    said = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # bench-run says what to start, then waits for it
            said.append(line)
            wanted = re.search(r"start it with (.*) and the settings in (\S+)$", line.strip())
            if wanted:
                break
        assert wanted, "".join(said) + (proc.stderr.read() if proc.stderr else "")
        exports = "".join(f"export {setting}\n" for setting in wanted.group(1).split())
        (tmp_path / "start.sh").write_text(f"""#!/usr/bin/env bash
set -a; . {wanted.group(2)}; set +a
{exports}setsid {FIRMWARE / 'zenoh-node'} >>{tmp_path}/device.out 2>&1 </dev/null &
echo $! >{tmp_path}/pid
""")
        (tmp_path / "start.sh").chmod(0o755)
        subprocess.run([str(tmp_path / "start.sh")], check=True, timeout=10)
        out, err = proc.communicate(timeout=900)
    finally:
        proc.kill()
        if (tmp_path / "pid").exists():  # the device is the caller's: the test stops it
            subprocess.run(["kill", "-KILL", "--", f"-{(tmp_path / 'pid').read_text().strip()}"], capture_output=True)
    out = "".join(said) + out
    assert proc.returncode == 0, out[-4000:] + err[-4000:]
    run_dir = REPO / attempts(subprocess.CompletedProcess([], 0, out, ""))[-1]
    cases = junit_cases(run_dir)
    for check in ("faults_injected", "recovery", "integrity", "ordering", "zenoh_to_can", "bridge_stats_agree"):
        assert cases[f"test_check[{check}]"] == "passed", cases
    assert (tmp_path / "calls").read_text().splitlines() == [
        "stop bridge_term", "start bridge_term", "stop bridge_kill", "start bridge_kill"]
    windows = json.loads((run_dir / "metrics.json").read_text())["faults"]["windows"]
    stops = [w for w in windows if w["action"].startswith("bridge_")]
    assert all(not w["error"] and w["end_ns"] - w["start_ns"] >= 0.5e9 for w in stops), stops  # the hold's 0.5 s
    assert (tmp_path / "device.out").read_text().count("ready: zid") == 3  # started by hand, then twice by the hook
    assert "DEVICE_HOOK start bridge_kill" in (run_dir / "device.log").read_text()
    assert leftovers(run_dir) == [] and not list(run_dir.glob("device.re*"))
