"""Checks that compare with something outside the run (a baseline run) on
hand-made results: they pass on noise and fail on a real regression."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from canbench import checks

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
