"""Checks that compare with something outside the run (a baseline run) on
hand-made results: they pass on noise and fail on a real regression."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from canbench import checks, put_order
from canbench import faults as faults_mod

pytestmark = pytest.mark.unit


def result(p50_now: float, p50_before: float | None, gate: dict, base_scenario: str = "smoke") -> SimpleNamespace:
    def metrics(p50, scenario="smoke"):
        return {"schema_version": 1, "run_id": f"r-{scenario}", "scenario": scenario,
                "can_to_zenoh": {"vcan0": {"latency": {"p50_ms": p50}}}}
    return SimpleNamespace(scenario=SimpleNamespace(expect={"latency": {"can_to_zenoh": gate}}),
                           metrics=metrics(p50_now),
                           baseline=metrics(p50_before, base_scenario) if p50_before is not None else None)


def test_regression_beyond_threshold_fails_naming_both_runs():
    problems = checks.latency_regression(result(0.9, 0.5, {"max_regression_pct": 50}))
    assert problems and "0.900 ms vs 0.500 ms" in problems[0] and "+80%" in problems[0]


@pytest.mark.parametrize("now,before", [(0.7, 0.5), (0.09, 0.05), (0.3, 0.5)])
def test_within_threshold_or_below_the_noise_floor_passes(now, before):
    assert checks.latency_regression(result(now, before, {"max_regression_pct": 50})) == []


def test_a_baseline_of_another_scenario_is_refused_not_compared():
    assert checks.latency_regression(result(0.9, 0.5, {"max_regression_pct": 50}, "can-fd-smoke")) == [
        "the baseline run r-can-fd-smoke has scenario 'can-fd-smoke', this run 'smoke': no comparison "
        "(give a run of this scenario)"]


def test_a_baseline_of_zero_says_so_without_a_percentage():
    assert checks.latency_regression(result(0.9, 0.0, {"max_regression_pct": 50})) == [
        "can_to_zenoh vcan0: p50 0.900 ms vs 0.000 ms in baseline run r-smoke (from a baseline of 0 or below > 50%)"]


def test_no_baseline_or_no_gate_is_not_judged():
    assert checks.latency_regression(result(0.9, None, {"max_regression_pct": 50})) is None
    assert checks.latency_regression(result(0.9, 0.5, {"p50_ms": 5})) is None


def soak_result(rss: list[float], fds: list[int], expect: dict) -> SimpleNamespace:
    hour_ns = 3_600_000_000_000
    rss_samples = [(i * hour_ns // len(rss), m) for i, m in enumerate(rss)]
    faults = {"bridge_rss_mib": {"max": max(rss), "samples": len(rss),
                                 "slope_mib_per_h": faults_mod.rss_slope_mib_per_h(rss_samples)},
              "bridge_fds": {"max": max(fds), "samples": len(fds), "growth": faults_mod.fd_growth(fds)}}
    return SimpleNamespace(scenario=SimpleNamespace(expect=expect), metrics={"faults": faults})


def test_a_leaking_bridge_fails_the_soak_gates_a_flat_one_passes():
    expect = {"bridge_rss_mib": 64, "bridge_rss_slope_mib_per_h": 2, "bridge_fd_growth": 0}
    flat = soak_result([20 + (i % 3) * 0.1 for i in range(100)], [12, 13, 12] * 10, expect)
    assert checks.bridge_memory(flat) == [] and checks.bridge_fds(flat) == []
    # start-up growth (the first tenth) is not a leak
    warm = soak_result([5 + i for i in range(10)] + [20.0] * 90, [12] * 30, expect)
    assert checks.bridge_memory(warm) == []
    leaking = soak_result([20 + i * 0.1 for i in range(100)], list(range(12, 42)), expect)
    assert "grows 10.0 MiB/h > gate 2 MiB/h" in checks.bridge_memory(leaking)[0]
    assert checks.bridge_fds(leaking) == ["bridge descriptors grew by 23 > gate 0"]


def test_too_few_samples_cannot_pass_a_soak_gate():
    few = soak_result([20.0] * 5, [12] * 3, {"bridge_rss_slope_mib_per_h": 2, "bridge_fd_growth": 0})
    assert "too few memory samples" in checks.bridge_memory(few)[0]
    assert "too few descriptor samples" in checks.bridge_fds(few)[0]



def test_a_device_of_your_own_is_not_judged_on_what_only_the_benchs_container_shows():
    # no memory or descriptor sample of a device on the host: not judged, said why, never a pass or a fail
    unsampled = {"max": None, "samples": 0, "slope_mib_per_h": None}
    run = SimpleNamespace(scenario=SimpleNamespace(expect={"bridge_rss_mib": 32, "bridge_fd_growth": 0}),
                          metrics={"faults": {"bridge_rss_mib": unsampled,
                                              "bridge_fds": {"max": None, "samples": 0, "growth": None}},
                                   "device": "host:7448", "validity": {"outcome": "valid"}})
    assert checks.bridge_memory(run) is None and checks.bridge_fds(run) is None
    run.metrics["device"] = None  # the bench's own bridge with no sample: a failure, as before
    assert checks.bridge_memory(run) == ["no memory sample of the bridge"]
STALE_SCENARIO = """name: stale
description: commands, one entry stamped too old when put
duration_s: 5
buses: [{name: vcan0}]
ecus:
  - {name: engine, bus: vcan0, role: periodic, run_s: 1, messages: [{id: "0C0", cycle_ms: 10}]}
commands:
  - {bus: vcan0, run_s: 1, messages: [{id: "6A0", cycle_ms: 20}]}
  - {bus: vcan0, run_s: 1, stamp_age_ms: 500, messages: [{id: "6B0", cycle_ms: 200}]}
bridge: {tx_max_age_ms: %s}
expect: {integrity: true}
"""


def stale_result(tmp_path, sent: list[tuple[int, int, int | None]], stale: int | None, lost_in_faults: int = 0,
                 windows: list[dict] | None = None, deadline: int = 100) -> SimpleNamespace:
    """sent: (id, put ms, bus ms or None = never reached the bus); stale: the bridge's tx_rejected.stale."""
    from canbench import oracle, scenario, wire
    path = tmp_path / "stale.yaml"
    path.write_text(STALE_SCENARIO % deadline)
    sc = scenario.load(path)
    ms = 1_000_000
    cmds, matched = [], []
    for i, (can_id, put, bus) in enumerate(sent):
        s = oracle.Observed(wire.Frame(can_id, 1, bytes([i])), 10**18 + put * ms, i, line=i + 2, origin="commands.tsv")
        cmds.append(s)
        if bus is not None:
            matched.append((s, oracle.Observed(s.frame, 10**18 + bus * ms, i, line=100 + i)))
    lost = [oracle.Observed(wire.Frame(0x6A0, 1, b"\xff"), 10**18 + w, 0) for w in range(lost_in_faults)]
    tx = SimpleNamespace(matched=matched, corrupted=[], lost_in_faults=lost)
    stats = {"buses": [{"bus": "vcan0", "tx_rejected": {"stale": stale}}]} if stale is not None else None
    faults = {"windows": windows or []}
    return SimpleNamespace(scenario=sc, buses=[SimpleNamespace(bus="vcan0", zenoh_to_can=tx, commands=cmds)],
                           bridge_stats=stats, metrics={"faults": faults})


def test_commands_within_the_deadline_pass(tmp_path):
    r = stale_result(tmp_path, [(0x6A0, 0, 1), (0x6A0, 20, 21), (0x6A0, 40, 160)], stale=0)
    assert checks.no_stale_commands(r) == []  # 120 ms: the deadline and the write's slack
    assert r.metrics["freshness"]["vcan0"]["max_age_ms"] == 120.0


def test_a_command_reaching_the_bus_after_the_deadline_fails_naming_it(tmp_path):
    problems = checks.no_stale_commands(stale_result(tmp_path, [(0x6A0, 0, 1), (0x6A0, 20, 2020)], stale=0))
    assert problems and "1 of 2 commands reached the bus older than the deadline 100 ms + 20 ms (oldest 2000.0 ms)" in \
        problems[0] and "commands.tsv:3" in problems[0] and "can.log:101" in problems[0]


def test_a_command_stamped_too_old_must_be_refused(tmp_path):
    # 6B0 is stamped 500 ms before its put: on the bus 1 ms after the put it is 501 ms old
    written = checks.no_stale_commands(stale_result(tmp_path, [(0x6A0, 0, 1), (0x6B0, 0, 1)], stale=0))
    assert written and "501.0 ms" in written[0]
    refused = stale_result(tmp_path, [(0x6A0, 0, 1), (0x6B0, 0, None)], stale=1)
    assert checks.no_stale_commands(refused) == []
    assert refused.metrics["freshness"]["vcan0"]["stamped_stale_refused"] == 1


def test_stale_refusals_are_attributed_to_fault_windows(tmp_path):
    s = 10**18
    windows = [{"action": "router_pause", "start_s": 1.0, "start_ns": s, "end_ns": s + 2 * 10**9},
               {"action": "partition", "start_s": 5.0, "start_ns": s + 5 * 10**9, "end_ns": s + 8 * 10**9}]
    r = stale_result(tmp_path, [(0x6A0, 0, 1)], stale=3, lost_in_faults=3, windows=windows)
    assert checks.no_stale_commands(r) == []
    assert [w["lost"] for w in r.metrics["freshness"]["vcan0"]["lost_per_window"]] == [3, 0]
    # refused as stale with no stalled link to explain it: a bridge throwing fresh commands away
    unexplained = checks.no_stale_commands(stale_result(tmp_path, [(0x6A0, 0, 1)], stale=5, lost_in_faults=3))
    assert unexplained and "refused 5 commands as stale; only 3 are explained" in unexplained[0]


def test_no_deadline_is_not_judged(tmp_path):
    assert checks.no_stale_commands(stale_result(tmp_path, [(0x6A0, 0, 5000)], stale=0, deadline=0)) is None


def obs(can_id, i):
    from canbench import oracle, wire
    return oracle.Observed(wire.Frame(can_id, 1, b"\x01", can_id > 0x7FF), i, i, line=i + 2, origin="commands.tsv")


def written_result(put: list[int], written: list[int]) -> SimpleNamespace:
    """zenoh_to_can's input: commands of these ids put in this order, carried by the bus in the order
    of their put positions in `written`."""
    commands = [obs(can_id, i) for i, can_id in enumerate(put)]
    matched = [(commands[i], commands[i]) for i in written]
    c = SimpleNamespace(lost=[], duplicates=[], corrupted=[], unexpected=[], matched=matched,
                        reordered=put_order.overtaken_commands(matched))  # as analysis sets it
    return SimpleNamespace(scenario=SimpleNamespace(commands=[object()], expect={}),
                           buses=[SimpleNamespace(bus="vcan0", zenoh_to_can=c, commands=[object()])])


def reorder_result(pairs: list[tuple[int, int]]) -> SimpleNamespace:
    """Each pair: a command, then one put after it that the bus carried first."""
    return written_result([i for pair in pairs for i in pair],
                          [k for n in range(len(pairs)) for k in (2 * n + 1, 2 * n)])


def test_a_command_overtaken_by_a_higher_priority_one_is_in_order():
    assert checks.zenoh_to_can(reorder_result([(0x200, 0x100)])) == []  # 0x100 waited with 0x200 and won
    assert checks.zenoh_to_can(reorder_result([(0x100 << 18 | 5, 0x100)])) == []  # standard before extended
    for pairs in ([(0x100, 0x200)], [(0x100, 0x100)]):  # lower priority first, or one id out of order
        problems = checks.zenoh_to_can(reorder_result(pairs))
        assert problems and "1 commands out of put order" in problems[0], pairs
    assert put_order.arbitration_key(SimpleNamespace(can_id=0x100, extended=False, remote=True)) < \
        put_order.arbitration_key(SimpleNamespace(can_id=0x100 << 18, extended=True, remote=False))


def test_every_command_that_overtook_one_is_looked_at_not_only_the_latest_put():
    # put 500, 600, 100; the bus carried 600, 100, 500: 100 may overtake 500, 600 may not
    problems = checks.zenoh_to_can(written_result([0x500, 0x600, 0x100], [1, 2, 0]))
    assert problems == ["vcan0: 1 commands out of put order: 500#01 (commands.tsv:2) after 600#01 (commands.tsv:3)"]
    assert checks.zenoh_to_can(written_result([0x500, 0x300, 0x100], [1, 2, 0])) == []  # both of higher priority
    assert checks.zenoh_to_can(written_result([0x100, 0x200, 0x300], [0, 1, 2])) == []


def test_metrics_count_the_commands_out_of_put_order_as_the_verdict_does(tmp_path):
    # put 6B0 then 6A0 (the bus carries 6A0 first: it won arbitration, in order), then two 6A0 that
    # the bus carries swapped (out of order): metrics.json and the report say 1, as the verdict does
    from synthetic import write_command_run

    from canbench import analysis, scenario, wire
    sc = scenario.load(Path(__file__).resolve().parents[2] / "scenarios" / "stale-commands.yaml")
    t0, ms = 1_700_000_000 * 10**9, 1_000_000
    a, b = wire.Frame(0x6A0, 1, b"\x01"), wire.Frame(0x6B0, 1, b"\x02")
    a2, a3 = wire.Frame(0x6A0, 1, b"\x03"), wire.Frame(0x6A0, 1, b"\x04")
    write_command_run(tmp_path, t0, 50, [(1, t0 + 100 * ms, b, t0 + 103 * ms), (2, t0 + 101 * ms, a, t0 + 102 * ms),
                                        (3, t0 + 200 * ms, a2, t0 + 203 * ms), (4, t0 + 201 * ms, a3, t0 + 202 * ms)])
    result = analysis.analyse(sc, "order", tmp_path, "vehicle/can", {}, None, 1.0)
    problems = checks.zenoh_to_can(result)
    assert len(problems) == 1 and "1 commands out of put order" in problems[0] and "6A0#03" in problems[0]
    counts = result.metrics["zenoh_to_can"]["vcan0"]
    assert (counts["reordered"], counts["reordered_per_id"]) == (1, 1)


def stale_scenario_run(run_dir, write_stamped_stale: bool):
    """stale-commands.yaml analysed without its fault steps, as the host fault test runs it: an ECU
    frame every 10 ms, the 6A0 commands written 1 ms after their put, the 6B0 ones (stamped 400 ms
    before their put) refused as the bridge must, or written by a bridge that ignores the deadline."""
    from synthetic import write_command_run

    from canbench import analysis, commands, oracle, scenario
    sc = scenario.load(Path(__file__).resolve().parents[2] / "scenarios" / "stale-commands.yaml")
    t0, ms = 1_700_000_000 * 10**9, 1_000_000
    sent = []
    for offset, _bus, line, f in commands.plan(sc)[:60]:
        put = t0 + int(offset * 1e9) + 3 * ms
        sent.append((line, put, f, None if f.can_id == 0x6B0 and not write_stamped_stale else put + ms))
    write_command_run(run_dir, t0, 50, sent)
    written = sum(on_bus is not None for *_, on_bus in sent)
    refused = len(sent) - written
    stats = {"buses": [{"bus": "vcan0", "published_frames": 50, "tx_frames": written,
                        "tx_rejected": {"stale": refused}}]}
    return analysis.analyse(sc, "stale", run_dir, "vehicle/can", {}, stats, 1.0), oracle


@pytest.mark.parametrize("write_stamped_stale", [False, True])
def test_stale_commands_scenario_fails_only_no_stale_commands_when_the_deadline_is_ignored(tmp_path,
                                                                                           write_stamped_stale):
    result, _ = stale_scenario_run(tmp_path, write_stamped_stale)
    assert checks.zenoh_to_can(result) == []  # the refused ones are not lost, the written ones in order
    assert result.metrics["zenoh_to_can"]["vcan0"]["lost"] == 0
    assert checks.bridge_stats_agree(result) == []
    problems = checks.no_stale_commands(result)
    if write_stamped_stale:
        assert problems and "older than the deadline 100 ms" in problems[0] and "6B0#" in problems[0]
    else:
        assert problems == []
        assert result.metrics["freshness"]["vcan0"]["stamped_stale_refused"] == \
            result.metrics["freshness"]["vcan0"]["refused_stale"] > 0
