"""Checks that compare with something outside the run (a baseline run) on
hand-made results: they pass on noise and fail on a real regression."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from canbench import checks
from canbench import faults as faults_mod

pytestmark = pytest.mark.unit


def result(p50_now: float, p50_before: float | None, gate: dict) -> SimpleNamespace:
    def metrics(p50):
        return {"run_id": "r", "can_to_zenoh": {"vcan0": {"latency": {"p50_ms": p50}}}}
    return SimpleNamespace(scenario=SimpleNamespace(expect={"latency": {"can_to_zenoh": gate}}),
                           metrics=metrics(p50_now), baseline=metrics(p50_before) if p50_before else None)


def test_regression_beyond_threshold_fails_naming_both_runs():
    problems = checks.latency_regression(result(0.9, 0.5, {"max_regression_pct": 50}))
    assert problems and "0.900 ms vs 0.500 ms" in problems[0] and "+80%" in problems[0]


@pytest.mark.parametrize("now,before", [(0.7, 0.5), (0.09, 0.05), (0.3, 0.5)])
def test_within_threshold_or_below_the_noise_floor_passes(now, before):
    assert checks.latency_regression(result(now, before, {"max_regression_pct": 50})) == []


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
