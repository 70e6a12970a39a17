"""A command the link delivers late is refused as stale by the bridge, as it must be: the oracle
excuses such a refusal only when the bench can see the lateness (the next command of the same id
reached the bus more than the deadline after the refused one's source time) and the bridge counted
it (tx_rejected.stale). Fresh commands refused, or commands lost without being counted, still fail."""
from __future__ import annotations

import json

import pytest
from synthetic import write_command_run

from canbench import analysis, checks, commands, oracle, scenario, wire

pytestmark = pytest.mark.unit

SCENARIO = """name: late
description: commands through a link that stalls
duration_s: 5
buses: [{name: vcan0}]
ecus:
  - {name: engine, bus: vcan0, role: periodic, run_s: 1, messages: [{id: "0C0", cycle_ms: 10}]}
commands:
  - {bus: vcan0, run_s: 1, messages: [{id: "6A0", cycle_ms: 20}]}
bridge: {tx_max_age_ms: 100}
expect: {integrity: true}
"""
T0, MS = 1_700_000_000 * 10**9, 1_000_000


def late_run(run_dir, delays_ms: list[int | None], refused: int, fence_ms: float | None = None):
    """Commands 6A0 put every 20 ms, each written to the bus delays_ms[i] after its put (None: never);
    refused: the bridge's tx_rejected.stale; fence_ms: the commander's fence (commands-arrived.json),
    that long after the last put (None: no file, as a run before the fence)."""
    path = run_dir / "late.yaml"
    path.write_text(SCENARIO)
    sc = scenario.load(path)
    sent = []
    for i, delay in enumerate(delays_ms):
        put = T0 + i * 20 * MS
        sent.append((i + 2, put, wire.Frame(0x6A0, 1, bytes([i])), None if delay is None else put + delay * MS))
    write_command_run(run_dir, T0, 20, sent)
    if fence_ms is not None:
        last_put = T0 + (len(delays_ms) - 1) * 20 * MS
        commands.arrivals_path(run_dir / "commands.tsv").write_text(json.dumps(
            {"vcan0": {"sent": len(delays_ms), "all_arrived_by_ns": last_put + int(fence_ms * MS)}}))
    written = sum(d is not None for d in delays_ms)
    stats = {"buses": [{"bus": "vcan0", "published_frames": 20, "tx_frames": written,
                        "tx_rejected": {"stale": refused}}]}
    return analysis.analyse(sc, "late", run_dir, "vehicle/can", {}, stats, 1.0)


# a 130 ms stall of the link: commands 3 and 4 reach the bridge older than 100 ms and are refused,
# command 5 (put 40 ms after 3) reaches the bus 95 ms after its own put, 135 ms after 3's
STALLED = [1, 1, 1, None, None, 95, 75, 55, 35, 16]  # 5 to 9 written together at 195-196 ms


def test_refusals_after_a_stalled_link_are_not_losses(tmp_path):
    result = late_run(tmp_path, STALLED, refused=2)
    assert checks.zenoh_to_can(result) == []
    assert result.metrics["zenoh_to_can"]["vcan0"]["lost"] == 0
    assert checks.no_stale_commands(result) == []
    fresh = result.metrics["freshness"]["vcan0"]
    assert fresh["refused_after_late_delivery"] == 2
    assert "the next 6A0 reached the bus 135.0 ms after this one's source time" in fresh["refused_late_examples"][0]


def test_fresh_commands_refused_fail_both_checks(tmp_path):
    # no stall: command 5 reaches the bus 1 ms after its put, so 3 and 4 reached the bridge young
    result = late_run(tmp_path, [1, 1, 1, None, None, 1, 1, 1, 1, 1], refused=2)
    lost = checks.zenoh_to_can(result)
    assert lost and "2 commands never reached the bus" in lost[0] and "commands.tsv:5" in lost[0]
    stale = checks.no_stale_commands(result)
    assert stale and "refused 2 commands as stale; only 0 are explained" in stale[0] and "0 delivered late" in stale[0]


@pytest.mark.parametrize("refused, lost", [(0, 2), (1, 1)])
def test_commands_lost_but_not_counted_as_stale_stay_lost(tmp_path, refused, lost):
    # the same stall, but the bridge counted fewer refusals than commands missing: the rest it lost
    result = late_run(tmp_path, STALLED, refused=refused)
    problems = checks.zenoh_to_can(result)
    assert problems and f"{lost} commands never reached the bus" in problems[0]
    assert checks.no_stale_commands(result) == []
    assert result.metrics["freshness"]["vcan0"]["refused_after_late_delivery"] == refused


def test_a_last_command_refused_has_no_later_evidence(tmp_path):
    # nothing of its id reached the bus after it: the bench cannot see it was late
    result = late_run(tmp_path, [1, 1, 1, 1, 1, 1, 1, 1, 1, None], refused=1)
    assert "1 commands never reached the bus" in checks.zenoh_to_can(result)[0]
    assert "only 0 are explained" in checks.no_stale_commands(result)[0]


# the stream's last three commands held 130 ms by a stalled link and refused: no later 6A0 on the bus,
# but the commander's fence (the bridge counted every command only 130 ms after the last put) shows it
TAIL_HELD = [1, 1, 1, 1, 1, 1, 1, None, None, None]


def test_a_stream_s_last_commands_refused_after_a_stall_are_shown_late_by_the_fence(tmp_path):
    result = late_run(tmp_path, TAIL_HELD, refused=3, fence_ms=130)
    assert checks.zenoh_to_can(result) == []
    assert checks.no_stale_commands(result) == []
    fresh = result.metrics["freshness"]["vcan0"]
    assert fresh["refused_after_late_delivery"] == 3
    assert "only 130.0 ms after this one's source time (the commander's fence)" in fresh["refused_late_examples"][-1]


@pytest.mark.parametrize("fence_ms", [None, 3])
def test_a_stream_s_last_commands_refused_fresh_fail_with_or_without_the_fence(tmp_path, fence_ms):
    # the fence 3 ms after the last put: the bridge had all of them young, yet refused three
    result = late_run(tmp_path, TAIL_HELD, refused=3, fence_ms=fence_ms)
    lost = checks.zenoh_to_can(result)
    assert lost and "commands never reached the bus" in lost[0]
    assert "only" in checks.no_stale_commands(result)[0]


def test_the_fence_bounds_only_as_far_as_it_reaches(tmp_path):
    # fence 60 ms after the last put: the last (put 0 ms before it) and the one put 20 ms before are
    # 60 and 80 ms old at most there, under the 100 ms deadline; the one 40 ms before, 100 ms: not over
    result = late_run(tmp_path, TAIL_HELD, refused=3, fence_ms=60)
    assert "3 commands never reached the bus" in checks.zenoh_to_can(result)[0]
    result = late_run(tmp_path, TAIL_HELD, refused=3, fence_ms=61)  # the first of them 101 ms old
    assert "2 commands never reached the bus" in checks.zenoh_to_can(result)[0]


def test_the_fence_bounds_only_commands_put_after_the_bus_s_last_one_on_the_bus():
    # 7E1 every 100 ms, its last put 90 ms before the stream's last 600 (which reached the bus): a fence
    # 20 ms after that is 110 ms after the lost 7E1, yet it says nothing of it, only of the stream's tail
    def cmd(i, can_id, t_ms):
        return oracle.Observed(wire.Frame(can_id, 1, bytes([i])), T0 + t_ms * MS, i, line=i + 2, origin="commands.tsv")
    last_7e1, last_600 = cmd(0, 0x7E1, 0), cmd(1, 0x600, 90)
    on_bus = oracle.Observed(last_600.frame, last_600.t_ns + MS, 0)
    fence_ns = last_600.t_ns + 20 * MS
    assert commands.delivered_late("vcan0", [last_7e1], [(last_600, on_bus)], {}, 100 * MS, fence_ns) == []
    # the same 7E1 put after the last command that reached the bus: the tail, which the fence bounds
    tail_7e1 = cmd(2, 0x7E1, 95)
    late = commands.delivered_late("vcan0", [tail_7e1], [(last_600, on_bus)], {}, 10 * MS, fence_ns)
    assert late == [(tail_7e1, 15.0, "fence")]


def flood_windows(start_ms: float, end_ms: float) -> dict:
    return {"windows": [{"action": "can_flood", "service": "orchestrator", "start_s": start_ms / 1000,
                         "end_s": end_ms / 1000, "start_ns": T0 + int(start_ms * MS),
                         "end_ns": T0 + int(end_ms * MS), "error": ""}]}


def test_a_command_late_behind_a_flood_is_the_emulated_bus_s_not_the_bridge_s(tmp_path):
    """A flood on the emulated bus (first come, first served) holds a written command behind its
    backlog: late while the flood lasts is counted, not failed; the same lateness without a flood fails."""
    delays = [1, 1, 1, 127, 1, 1]  # command 4 reaches the bus 127 ms after its put
    plain = late_run(tmp_path, delays, refused=0)
    stale = checks.no_stale_commands(plain)
    assert stale and "1 of 6 commands reached the bus older than the deadline" in stale[0]
    flooded_dir = tmp_path / "flooded"
    flooded_dir.mkdir()
    flooded = late_run(flooded_dir, delays, refused=0)
    flooded.metrics["faults"] = flood_windows(50, 150)
    assert checks.no_stale_commands(flooded) == []
    fresh = flooded.metrics["freshness"]["vcan0"]
    assert fresh["late"] == 0 and fresh["late_in_floods"] == 1
    assert "during a flood" in fresh["late_in_floods_examples"][0]


def test_a_command_late_well_after_a_flood_still_fails(tmp_path):
    result = late_run(tmp_path, [1, 1, 1, 127, 1, 1], refused=0)
    result.metrics["faults"] = flood_windows(-3000, -2000)  # ended 2 s before: more than the settle time
    stale = checks.no_stale_commands(result)
    assert stale and "1 of 6 commands reached the bus older than the deadline" in stale[0]
