"""scripts/bench-suite (make test) with Docker and bench-run replaced by stand-ins: the
validation gate (exit 2, no run started), JOBS=N at most N runs at once, SHARD=k/n runners
together running every scenario once, one summary and one exit code."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]

# `docker run [--rm] [-v h:c[:ro]] [-w d] [-u x] [-e K[=v]] image cmd...` run on the host:
# container paths of the mounts mapped back, `canbench` the checkout's
FAKE_DOCKER = f"""#!{sys.executable}
import os, subprocess, sys
args, i, mounts, cwd, env = sys.argv[1:], 1, {{}}, None, dict(os.environ)
if args[0] == "image":  # `docker image inspect`: every image is there
    sys.exit(0)
while args[i].startswith("-"):
    flag = args[i]
    if flag == "--rm":
        i += 1
        continue
    value = args[i + 1]
    if flag == "-v":
        host, cont = value.split(":")[:2]
        mounts[cont] = host
    elif flag == "-w":
        cwd = value
    elif flag == "-e" and "=" in value:
        env[value.split("=")[0]] = value.split("=", 1)[1]
    i += 2
def host(x):
    for c, h in mounts.items():
        if x == c or x.startswith(c + "/"):
            return h + x[len(c):]
    return x
with open(os.environ["FAKE_LOG"], "a") as log:
    log.write("docker " + " ".join(args[i + 1:]) + "\\n")
sys.exit(subprocess.run([host(x) for x in args[i + 1:]], cwd=cwd, env=env).returncode)
"""
CANBENCH = f"#!/bin/sh\nPYTHONPATH={REPO} exec {sys.executable} -m canbench.cli \"$@\"\n"
# bench-run's contract towards the suite: a line in runs.tsv, the checks' exit code
FAKE_BENCH_RUN = """#!/usr/bin/env bash
s=$1 name=$(basename "$1" .yaml)
echo "start $name $(date +%s%N)" >>"$FAKE_LOG"
code=$(sed -n 's/^# exit: //p' "$s")
if [ -n "${FAKE_MEET:-}" ]; then # runs that must meet: wait (FAKE_MEET_S at most) for the group of FAKE_MEET
	started=$(grep -c '^start ' "$FAKE_LOG") # this run's place among the starts
	group_end=$(((started + FAKE_MEET - 1) / FAKE_MEET * FAKE_MEET))
	for _ in $(seq $((${FAKE_MEET_S:-30} * 100))); do
		[ "$(grep -c '^start ' "$FAKE_LOG")" -ge "$group_end" ] && break
		sleep 0.01
	done
fi
if [ -n "${FAKE_UNTIL:-}" ]; then # a longer run: until the suite's output shows FAKE_UNTIL (30 s at most)
	for _ in $(seq 300); do grep -qF "$FAKE_UNTIL" "$FAKE_OUT" && break; sleep 0.1; done
fi
echo "stop $name $(date +%s%N)" >>"$FAKE_LOG"
printf '%s\\t%s\\t%s\\t%s\\n' "$s" "run-$name" "${code:-0}" 1 >>"$BENCH_SUITE_DIR/runs.tsv"
exit "${code:-0}"
"""
SCENARIO = ("name: {name}\nduration_s: {duration}\nbuses: [{{name: vcan0}}]\n"
            "ecus: [{{name: e, bus: vcan0, role: echo, echo_ids: ['600']}}]\nexpect: {{integrity: true}}\n")


@pytest.fixture
def bench(tmp_path):
    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    for script in ("bench-suite", "require-images", "device-preflight"):
        shutil.copy(REPO / "scripts" / script, root / "scripts")
    bins = tmp_path / "bin"
    bins.mkdir()
    for path, text in [(root / "scripts" / "bench-run", FAKE_BENCH_RUN), (bins / "docker", FAKE_DOCKER),
                       (bins / "canbench", CANBENCH)]:
        path.write_text(text)
        path.chmod(0o755)
    (root / "sc").mkdir()
    env = {**os.environ, "PATH": f"{bins}:{os.environ['PATH']}", "FAKE_LOG": str(tmp_path / "log")}

    def run(names: list[str], **extra: str) -> subprocess.CompletedProcess:
        """bench-suite on names; with OUT_FILE its stdout goes there as it is written (a run can wait on it)."""
        cmd = [str(root / "scripts" / "bench-suite"), *[f"sc/{n}.yaml" for n in names]]
        if "OUT_FILE" not in extra:
            return subprocess.run(cmd, cwd=root, env={**env, **extra}, capture_output=True, text=True, timeout=120)
        with open(extra["OUT_FILE"], "w") as out:
            proc = subprocess.run(cmd, cwd=root, env={**env, **extra}, stdout=out, stderr=subprocess.PIPE,
                                  text=True, timeout=120)
        proc.stdout = Path(extra["OUT_FILE"]).read_text()
        return proc

    def add(name: str, duration: int = 10, code: int = 0, text: str | None = None) -> None:
        body = text if text is not None else SCENARIO.format(name=name, duration=duration)
        (root / "sc" / f"{name}.yaml").write_text(body + (f"# exit: {code}\n" if code else ""))

    def events() -> list[tuple[str, str, int]]:
        log = tmp_path / "log"
        lines = log.read_text().splitlines() if log.exists() else []
        return [(w[0], w[1], int(w[2])) for w in (line.split() for line in lines) if w[0] in ("start", "stop")]

    return run, add, events, root


def overlap(events: list[tuple[str, str, int]]) -> int:
    running = peak = 0
    for kind, _, _ in sorted(events, key=lambda e: (e[2], e[0] == "start")):
        running += 1 if kind == "start" else -1
        peak = max(peak, running)
    return peak


def test_bad_scenario_stops_everything_with_exit_2(bench):
    run, add, events, root = bench
    add("good")
    add("bad", text="name: bad\nduration_s: ten\nbuses: [{name: vcan0}]\nexpect: {}\n")
    proc = run(["good", "bad"])
    assert proc.returncode == 2, proc.stderr
    assert "sc/bad.yaml:2: duration_s: 'ten' is not of type 'number'" in proc.stderr
    assert "nothing started" in proc.stderr and events() == []  # not even the good one
    assert not list((root / "reports").glob("suite-*"))


def test_jobs_run_concurrently_and_the_summary_covers_all(bench):
    run, add, events, root = bench
    for i in range(4):
        add(f"s{i}", code=1 if i == 2 else 0)
    proc = run([f"s{i}" for i in range(4)], JOBS="2", FAKE_MEET="2")  # each waits for its pair: seen side by side
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert overlap(events()) == 2
    assert "s2: FAILED (exit 1)" in proc.stdout and "make test: FAILED, 3 of 4 passed" in proc.stdout
    summary = json.loads(next((root / "reports").glob("suite-*/summary.json")).read_text())
    assert sorted((r["scenario"], r["exit_code"]) for r in summary["runs"]) == [
        ("sc/s0.yaml", 0), ("sc/s1.yaml", 0), ("sc/s2.yaml", 1), ("sc/s3.yaml", 0)]
    assert summary["jobs"] == 2 and (root / "reports" / "latest-suite" / "index.html").exists()


def test_progress_before_the_first_run_ends(bench, tmp_path):
    """The progress line counts 0 finished runs while the first still runs, and says nothing else
    (it once printed the shell's "runs.tsv: No such file or directory" first)."""
    run, add, events, root = bench
    add("long")
    out = tmp_path / "suite.out"
    proc = run(["long"], PROGRESS_S="0.2", FAKE_UNTIL="suite: 0 of 1 done; running: long", FAKE_OUT=str(out),
               OUT_FILE=str(out))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "suite: 0 of 1 done; running: long (" in out.read_text()
    assert "runs.tsv" not in proc.stderr and "No such file" not in proc.stderr, proc.stderr


def test_serial_is_one_at_a_time(bench):
    run, add, events, _ = bench
    for i in range(3):
        add(f"s{i}")
    # each waits a second for a second run beside it: one started beside it would be seen
    proc = run([f"s{i}" for i in range(3)], FAKE_MEET="2", FAKE_MEET_S="1")
    assert proc.returncode == 0 and overlap(events()) == 1, proc.stdout + proc.stderr
    assert "make test: all 3 scenario(s) passed" in proc.stdout


def test_shards_together_run_every_scenario_once(bench):
    run, add, events, _ = bench
    durations = [70, 60, 60, 50, 40, 30, 30, 10]
    for i, d in enumerate(durations):
        add(f"s{i}", duration=d)
    names = [f"s{i}" for i in range(len(durations))]
    for k in (1, 2, 3):
        proc = run(names, SHARD=f"{k}/3")
        assert proc.returncode == 0, proc.stdout + proc.stderr
    started = [name for kind, name, _ in events() if kind == "start"]
    assert sorted(started) == sorted(names)


FAULTED = ("name: {name}\nduration_s: 10\nbuses: [{{name: vcan0}}]\n"
           "ecus: [{{name: e, bus: vcan0, role: echo, echo_ids: ['600']}}]\nexpect: {{integrity: true}}\n"
           "faults: [{{at_s: 1, action: bridge_kill, duration_s: 0.5}}]\n")


def test_a_device_of_your_own_runs_what_it_can_and_says_what_it_cannot(bench):
    run, add, events, root = bench
    (root / "build" / "ucan").mkdir(parents=True)
    (root / "build" / "ucan" / "libucan-preload.so").write_text("")
    add("plain")
    add("faulted", text=FAULTED.format(name="faulted"))
    proc = run(["plain", "faulted"], DEVICE="host:7448")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert [name for kind, name, _ in events() if kind == "start"] == ["plain"]
    assert "not run against DEVICE=host:7448: " in proc.stderr and "faulted.yaml: fault steps" in proc.stderr
    # the summary lists it as not run, and the last line counts it apart from the runs
    assert "all 1 scenario(s) passed (1 not run against DEVICE=host:7448" in proc.stdout
    suite_dir = next((root / "reports").glob("suite-*"))
    summary = json.loads((suite_dir / "summary.json").read_text())
    left = [r for r in summary["runs"] if r["left_out"]]
    assert [r["scenario"] for r in left] == ["sc/faulted.yaml"] and summary["exit_code"] == 0
    assert "fault steps" in left[0]["verdict"]
    junit = (suite_dir / "junit.xml").read_text()
    assert "<skipped" in junit and "not run against the device" in junit
    assert "1 of 1 scenarios passed (1 not run against the device)" in (suite_dir / "index.html").read_text()
    # nothing it can run, or a DEVICE that is not host:PORT: bad input, nothing started
    for names, device, says in ((["faulted"], "host:7448", "none of the 1 scenario(s)"),
                                (["plain"], "192.168.1.1:7447", "expected host:PORT")):
        proc = run(names, DEVICE=device)
        assert proc.returncode == 2 and says in proc.stderr, proc.stdout + proc.stderr
    assert len([e for e in events() if e[0] == "start"]) == 1


@pytest.mark.parametrize("how", [{"DEVICE_CMD": "./my-gateway"}, {"DEVICE_HOOK": "./power.sh"}])
def test_a_device_the_bench_starts_or_has_a_hook_for_runs_the_steps_that_stop_it(bench, how):
    # with DEVICE_CMD bench-run stops the device and starts it again, with DEVICE_HOOK the user's hook
    # does: a bridge_kill is no reason to leave out
    run, add, events, root = bench
    (root / "build" / "ucan").mkdir(parents=True)
    (root / "build" / "ucan" / "libucan-preload.so").write_text("")
    add("faulted", text=FAULTED.format(name="faulted"))
    proc = run(["faulted"], DEVICE="host:7448", **how)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert [name for kind, name, _ in events() if kind == "start"] == ["faulted"]
    assert "not run against" not in proc.stderr + proc.stdout


def test_a_device_of_your_own_runs_one_scenario_at_a_time(bench):
    run, add, events, root = bench
    (root / "build" / "ucan").mkdir(parents=True)
    (root / "build" / "ucan" / "libucan-preload.so").write_text("")
    add("plain")
    proc = run(["plain"], DEVICE="host:7448", JOBS="2")
    assert proc.returncode == 2 and "JOBS=1, not 2" in proc.stderr
    assert events() == []


@pytest.mark.parametrize("env,says", [
    ({"DEVICE_CMD": "./my-gateway"}, "DEVICE_CMD is set but DEVICE is not"),
    ({"DEVICE": "host:7448", "BENCH_ACCESS": "open"}, "without TLS or ACL"),
    ({"DEVICE": "host:7448"}, "libucan-preload.so is missing (make ucan)"),
    ({"DEVICE": "host:7448 ", "DEVICE_CMD": "x"}, "expected host:PORT"),
    ({"DEVICE_ANNOUNCES": "0"}, "DEVICE_ANNOUNCES is set but DEVICE is not"),
    ({"DEVICE_HOOK": "./power.sh"}, "DEVICE_HOOK is set but DEVICE is not"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh", "DEVICE_CMD": "x"},
     "DEVICE_HOOK and DEVICE_CMD are both set"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh", "DEVICE_HOOK_TIMEOUT_S": "0"}, "DEVICE_HOOK_TIMEOUT_S=0"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh", "DEVICE_HOOK_TIMEOUT_S": "26"}, "expected 1-25 s"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh  # relay 2"}, "no comment, newline or trailing"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh;"}, "no comment, newline or trailing"),
    ({"DEVICE": "host:7448", "DEVICE_HOOK": "./power.sh\n"}, "no comment, newline or trailing"),
    ({"DEVICE": "host:7448", "DEVICE_ANNOUNCES": "no"}, "DEVICE_ANNOUNCES=no: expected 1"),
    ({"DEVICE": "host:7448", "DEVICE_ANNOUNCES": "0", "VIEWER": "1"}, "VIEWER with DEVICE_ANNOUNCES=0"),
])
def test_a_device_run_that_would_mislead_or_expose_is_refused_before_anything_starts(bench, env, says):
    run, add, events, root = bench
    add("plain")
    proc = run(["plain"], **env)
    assert proc.returncode == 2 and says in proc.stderr and "nothing started" in proc.stderr, proc.stderr
    assert events() == [] and not list((root / "reports").glob("suite-*"))
