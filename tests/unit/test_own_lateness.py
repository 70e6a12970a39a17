"""canbench.ecu.OwnLateness: what part of a replay ECU's send error is its own. A stop of the
process inside a send the bus was ready for is the ECU's (the frames due meanwhile go out late);
a wait for a full bus is not. The real ECU under SIGSTOP is tests/bus/test_ecu_lateness.py; this
places the stop exactly where that test can only hit by chance."""
from __future__ import annotations

import pytest

from canbench.ecu import OwnLateness
from canbench.stats import percentile

pytestmark = pytest.mark.unit

GAP_S = 0.005  # a frame every 5 ms
SEND_S = 0.00005  # what a send takes when nothing holds it up


def run(frames: int, held_at: set[int], hold_s: float, bus_wait: bool) -> list[float]:
    """Frames due every GAP_S, each sent on time unless behind; the sends of the frames in held_at
    are held for hold_s each, by a full bus (bus_wait) or by the process being stopped inside them."""
    own = OwnLateness()
    clock = 0.0
    for i in range(frames):
        due = i * GAP_S
        at = max(clock, due)
        held = hold_s if i in held_at else 0.0
        done = at + SEND_S + held
        own.sent(due=due, at=at, bus_wait=held if bus_wait else 0.0, done=done)
        clock = done
    return list(own.errors_ms)


def test_a_stop_inside_a_ready_send_makes_the_frames_due_meanwhile_late():
    errors = run(400, held_at={100}, hold_s=0.1, bus_wait=False)
    late = [e for e in errors if e > 5.0]
    assert len(late) == 18, late  # due 5-90 ms into the 100 ms stop: more than 5 ms before it ended
    assert max(errors) > 95.0


def test_three_stops_inside_sends_put_the_p95_over_5_ms():
    errors = run(388, held_at={60, 160, 260}, hold_s=0.1, bus_wait=False)
    assert percentile(errors, 0.95) > 5.0


def test_a_full_bus_that_holds_a_send_is_not_the_ecus_lateness():
    errors = run(400, held_at={100}, hold_s=0.1, bus_wait=True)
    assert max(errors) < 0.1, max(errors)


def test_frames_written_at_once_to_a_paced_bus_are_not_late():
    """A burst (every frame due at 0) to a bus that takes one frame per 0.25 ms once its queue is
    full: the ECU waits for the bus, and is never behind by its own doing."""
    own = OwnLateness()
    clock = 0.0
    for i in range(3000):
        wait = 0.00025 if i >= 256 else 0.0
        at = clock
        clock = at + SEND_S + wait
        own.sent(due=0.0, at=at, bus_wait=wait, done=clock)
    errors = list(own.errors_ms)
    assert percentile(errors, 0.95) < 0.1 and max(errors) < 13.0
