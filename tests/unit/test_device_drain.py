"""A device that announces nothing (DEVICE_ANNOUNCES=0) has no stats to say what it read: the run
drains on the capture (canbench.run.Execution._drain_unannounced), never before it holds what the
ECUs sent, whatever the device's own batching, and within a bound when the device lost frames."""
from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from canbench import run

pytestmark = pytest.mark.unit


class BatchingCapture:
    """A capture whose device publishes `per_batch` frames every `every_s` seconds, up to `total`."""

    def __init__(self, per_batch: int, every_s: float, total: int):
        self.started, self.per_batch, self.every_s, self.total = time.monotonic(), per_batch, every_s, total

    def frames_on(self, _keys) -> int:
        batches = int((time.monotonic() - self.started) / self.every_s)
        return min(self.total, batches * self.per_batch)


def drain(capture: BatchingCapture, sent: int, period_s: float = 0.0) -> float:
    """Drains a run whose ECUs sent `sent` frames; returns how long it took."""
    execution = SimpleNamespace(done={"engine": {"sent": sent - 5}, "tester": {"sent": 5}}, period_s=period_s,
                                zenoh_capture=capture, rx_keys={"vehicle/can/rx"})
    started = time.monotonic()
    run.Execution._drain_unannounced(execution)  # type: ignore[arg-type]
    return time.monotonic() - started


def test_a_device_batching_longer_than_the_quiet_time_is_drained_after_its_last_batch():
    # the scenario says immediate mode; the device batches every 0.6 s, longer than the 0.5 s of quiet
    capture = BatchingCapture(per_batch=10, every_s=0.6, total=40)
    drain(capture, sent=40)
    assert capture.frames_on(None) == 40  # the last batch came before the drain ended


def test_a_device_that_lost_frames_is_drained_within_the_bound(monkeypatch):
    monkeypatch.setattr(run, "DRAIN_TIMEOUT_S", 1.0)
    took = drain(BatchingCapture(per_batch=39, every_s=0.01, total=39), sent=40)
    assert 1.0 <= took < 1.0 + 0.2 + run.DEVICE_QUIET_S + 0.5
