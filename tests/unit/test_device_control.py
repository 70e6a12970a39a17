"""The orchestrator's side of a fault step on a device of your own (canbench.device_control):
the request bench-run reads, the window it answers taken as the fault's, and every way it can
go wrong said (nobody serving, an error, no answer, a stale answer). bench-run's side runs in
tests/compose/test_device.py."""
from __future__ import annotations

import os
import re
import threading
import time

import pytest

from canbench import device_control

pytestmark = pytest.mark.unit


class FakeBenchRun:
    """The FIFOs as bench-run makes and holds them (open both ways), answering a request with
    answer(seq): what bench-run writes back, its own SEQ included."""

    def __init__(self, run_dir, answer):
        self.requests: list[str] = []
        os.mkfifo(run_dir / device_control.REQUEST, 0o600)
        os.mkfifo(run_dir / device_control.REPLY, 0o600)
        self.request = os.open(run_dir / device_control.REQUEST, os.O_RDWR)
        self.reply = os.open(run_dir / device_control.REPLY, os.O_RDWR)
        self.answer = answer
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def serve(self) -> None:
        line = os.read(self.request, 4096).decode()
        self.requests.append(line)
        answer = self.answer(line.split()[0])
        if answer:
            os.write(self.reply, answer.encode())

    def close(self) -> None:
        self.thread.join(5)
        os.close(self.request)
        os.close(self.reply)


def test_the_request_says_the_step_and_its_hold_and_the_answer_is_the_window(tmp_path):
    host = FakeBenchRun(tmp_path, lambda seq: f"{seq} ok 1000 2500000000\n")
    assert device_control.restart(tmp_path, "bridge_kill", 0.5) == (1000, 2_500_000_000)
    host.close()
    [request] = host.requests  # one line, a plain decimal bench-run's shell reads
    assert re.fullmatch(r"\d+ bridge_kill 0\.500\n", request)


def test_an_answer_given_up_on_is_not_taken_for_the_next_one(tmp_path):
    # an earlier request's answer, in the pipe before the request, or arriving late after it
    host = FakeBenchRun(tmp_path, lambda seq: f"{seq}0 ok 3 4\n{seq} ok 5 6\n")
    os.write(host.reply, b"0 ok 1 2\n")
    assert device_control.restart(tmp_path, "bridge_term", 0) == (5, 6)
    host.close()


def test_bench_runs_error_is_said(tmp_path):
    host = FakeBenchRun(tmp_path, lambda seq: f"{seq} error bridge_pause is not a fault step on the device\n")
    with pytest.raises(RuntimeError, match="could not bridge_term the device: bridge_pause is not a fault step"):
        device_control.restart(tmp_path, "bridge_term", 0)
    host.close()


def test_no_answer_in_time_is_an_error_not_a_hang(tmp_path):
    host = FakeBenchRun(tmp_path, lambda seq: None)
    started = time.monotonic()
    with pytest.raises(RuntimeError, match="no answer from bench-run in time"):
        device_control.restart(tmp_path, "bridge_term", 0.1, margin_s=0.2)
    assert time.monotonic() - started < 5
    host.close()


def test_a_device_nobody_started_cannot_be_restarted(tmp_path):
    with pytest.raises(RuntimeError, match=r"only a device it started \(DEVICE_CMD\)"):
        device_control.restart(tmp_path, "bridge_kill", 0)
    # the FIFOs there, but nobody reading the requests: said at once
    os.mkfifo(tmp_path / device_control.REQUEST)
    os.mkfifo(tmp_path / device_control.REPLY)
    with pytest.raises(RuntimeError, match="does not serve"):
        device_control.restart(tmp_path, "bridge_kill", 0)
