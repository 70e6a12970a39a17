"""A command the link delivers late is refused as stale by the bridge, as it must be: the oracle
excuses such a refusal only when the bench can see the lateness (the next command of the same id
reached the bus more than the deadline after the refused one's source time) and the bridge counted
it (tx_rejected.stale). Fresh commands refused, or commands lost without being counted, still fail."""
from __future__ import annotations

import pytest
from synthetic import write_command_run

from canbench import analysis, checks, scenario, wire

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


def late_run(run_dir, delays_ms: list[int | None], refused: int):
    """Commands 6A0 put every 20 ms, each written to the bus delays_ms[i] after its put (None: never);
    refused: the bridge's tx_rejected.stale."""
    path = run_dir / "late.yaml"
    path.write_text(SCENARIO)
    sc = scenario.load(path)
    sent = []
    for i, delay in enumerate(delays_ms):
        put = T0 + i * 20 * MS
        sent.append((i + 2, put, wire.Frame(0x6A0, 1, bytes([i])), None if delay is None else put + delay * MS))
    write_command_run(run_dir, T0, 20, sent)
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
