"""`invalid: emulator` on a real replay ECU: the code `canbench ecu` runs for a replay
(canbench.ecu.replay, python-can on the bus fixture) sends the 2 s powertrain trace (388 frames,
~190 frames/s) while the test stops the process (SIGSTOP/SIGCONT) as a seeded fault. Stopped
3 x 100 ms, it sends ~60 frames up to 100 ms late: its own send error's p95 exceeds the default
5 ms and validity.emulator_problems names it. Stopped once for 20 ms (a scheduler stall of a
loaded machine), only ~4 frames are late: p95 stays under 5 ms and the run stays valid.

The ECU is replay() in a subprocess rather than `canbench ecu`: the command adds only the
run's Zenoh handshake (wait for the capture's token, publish the summary), no timing."""
from __future__ import annotations

import json
import signal
import sys
import textwrap
import time

import pytest
from conftest import REPO, require_userspace, wait_for

from canbench import scenario, validity
from canbench.analysis import RunResult

SCENARIO = REPO / "scenarios" / "smoke.yaml"  # one ECU, engine, replaying traces/powertrain-2s.log
TRACE_FRAMES = 388
BEHIND_MS = 5.0  # the documented default of expect.emulator_max_send_error_ms (smoke sets none)
SHORT_STALL_MAX_S = 0.05  # a longer stop than this is not the single short stall the case is about

REPLAY = textwrap.dedent("""\
    import json, sys
    from pathlib import Path
    from canbench import ecu, scenario
    sc = scenario.load(Path(sys.argv[1]))
    engine = next(e for e in sc.ecus if e.name == "engine")
    print(json.dumps(ecu.replay(engine, sc, Path(sys.argv[2]))), flush=True)
""")


def frames_logged(path) -> int:
    if not path.exists():
        return 0
    with open(path) as f:
        return sum(1 for line in f if not line.startswith("#"))


def replay_with_stops(bus, run_dir, stops: list[tuple[float, float]]) -> tuple[dict, list[float]]:
    """Replays the smoke scenario's trace, stopping the ECU for each (at_s, for_s), at_s counted
    from its first frame. Returns its summary and how long each stop really lasted (s)."""
    require_userspace(bus, "a timing test: the kernel lane may run under emulation, which paces nothing like the bench")
    run_dir.mkdir()
    proc = bus.popen([sys.executable, "-c", REPLAY, str(SCENARIO), str(run_dir)], cwd=REPO)
    stopped = []
    try:
        # its send log gets each frame's line just before the frame is sent: the replay has started
        wait_for(lambda: frames_logged(run_dir / "ecu-engine.sent.tsv") > 0 or proc.poll() is not None,
                 "the ECU's first frame")
        first = time.perf_counter()
        for at_s, for_s in stops:
            time.sleep(max(0.0, first + at_s - time.perf_counter()))  # the fault's schedule (pacing)
            assert proc.poll() is None, "the replay ended before the fault: " + proc.stderr.read()
            begin = time.perf_counter()
            proc.send_signal(signal.SIGSTOP)
            time.sleep(for_s)  # the fault itself: how long the ECU gets no CPU
            proc.send_signal(signal.SIGCONT)
            stopped.append(time.perf_counter() - begin)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGCONT)
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    return json.loads(out), stopped


def emulator_problems(run_dir, summary: dict) -> list[str]:
    """The verdict a run would get from its ECU summary and send log (no captures: no bus order)."""
    result = RunResult(scenario=scenario.load(SCENARIO), run_id="lateness", run_dir=run_dir, buses=[],
                       ecus={summary["name"]: summary}, bridge_stats=None, unexpected_keys=[])
    return validity.emulator_problems(result)


def test_an_ecu_stopped_3_times_100_ms_is_behind_its_trace(bus, tmp_path):
    run_dir = tmp_path / "run"
    summary, stopped = replay_with_stops(bus, run_dir, [(0.3, 0.1), (0.8, 0.1), (1.3, 0.1)])
    assert summary["sent"] == TRACE_FRAMES == frames_logged(run_dir / "ecu-engine.sent.tsv")
    own = summary["own_send_error_ms"]
    assert own["p95"] > BEHIND_MS, (
        f"stopped {[round(s * 1000) for s in stopped]} ms, yet own send error {own} "
        f"(against the trace: {summary['fidelity_ms']})")
    problems = emulator_problems(run_dir, summary)
    assert len(problems) == 1 and problems[0].startswith("ECU engine: p95 send error "), problems
    assert problems[0].endswith("it fell behind its trace"), problems


def test_one_20_ms_stall_leaves_the_ecu_on_its_trace(bus, tmp_path):
    run_dir = tmp_path / "run"
    summary, stopped = replay_with_stops(bus, run_dir, [(0.8, 0.02)])
    if stopped[0] > SHORT_STALL_MAX_S:
        pytest.fail(f"the 20 ms stop lasted {stopped[0] * 1000:.0f} ms (the test itself was held up): "
                    "not a short stall")
    assert summary["sent"] == TRACE_FRAMES
    own = summary["own_send_error_ms"]
    assert own["p95"] < BEHIND_MS, own
    assert emulator_problems(run_dir, summary) == []
