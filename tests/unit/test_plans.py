"""What an ECU and the commander send: the plans are made lazily (an hour of a
busy bus held as can.Message objects is gigabytes), so their order, their count
and the last frame (the own copies an ECU waits for) must come out exactly as if
every frame had been made up front."""
from __future__ import annotations

import tracemalloc

import can
import pytest

from canbench import commands, periodic, plans
from canbench.scenario import Commands, Ecu, Message
from canbench.trace_frames import TraceFrames
from canbench.wire import Frame

pytestmark = pytest.mark.unit

MESSAGES = [Message(0x100, 10), Message(0x0FF, 10), Message(0x18FEF100, 100, extended=True),
            Message(0x100, 25, dlc=2), Message(0x7E0, 1000, remote=True)]


def key(m: can.Message) -> tuple:
    return (round(m.timestamp, 9), m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.dlc, bytes(m.data))


def eager_periodic(messages, seconds: float, start: float) -> list[can.Message]:
    """The plan as it was made before (every frame, then one stable sort): the reference."""
    frames = [periodic.periodic_frame(m, n, start, "vcan0") for m in messages
              for n in range(periodic.periodic_count(m, seconds))]
    return sorted(frames, key=lambda f: (f.timestamp, f.arbitration_id))


def test_periodic_plan_is_the_sorted_frames_with_their_count_and_last():
    plan = plans.timed_plan([], 1.0, 1, 0.0, "vcan0", {})
    assert (plan.count, plan.last, list(plan.frames())) == (0, None, [])
    reference = eager_periodic(MESSAGES, 3.0, 0.5)
    lazy = list(periodic.periodic_frames(MESSAGES, 3.0, 0.5))
    assert [key(m) for m in lazy] == [key(m) for m in reference]
    last = periodic.periodic_last(MESSAGES, 3.0, 0.5)
    assert key(last) == key(reference[-1])


def test_ecu_schedule_counts_the_own_copies_of_the_last_id():
    e = Ecu(name="body", bus="vcan0", role="periodic", run_s=2.0, messages=tuple(MESSAGES), start_offset_s=0.1)
    plan = plans.schedule(e, None)
    frames = [m for _, m in plan.frames()]
    assert plan.count == len(frames) == len(eager_periodic(MESSAGES, 2.0, 0.1))
    assert key(plan.last) == key(frames[-1])
    assert plan.last_id_count == sum(1 for m in frames if (m.arbitration_id, m.is_extended_id)
                                     == (plan.last.arbitration_id, plan.last.is_extended_id))
    assert list(plan.frames()) and len(list(plan.frames())) == plan.count  # each call starts afresh


def test_timed_plan_loops_remaps_and_knows_its_last_frame():
    trace = TraceFrames("can0")
    for i, id_ in enumerate([0x10, 0x20, 0x10, 0x30]):
        trace.append(i + 1, 100_000_000_000 + i * 10_000_000, Frame(id_, 1, bytes([i])))  # 100 s + i * 10 ms
    plan = plans.timed_plan(trace, 2.0, 3, 1.0, "vcan1", {0x30: 0x10})
    frames = list(plan.frames())
    assert plan.count == len(frames) == 12
    assert [line for line, _ in frames] == [1, 2, 3, 4] * 3
    assert [m.arbitration_id for _, m in frames[:4]] == [0x10, 0x20, 0x10, 0x10]
    # loop period = span + first gap = 0.04 s, at speed 2: each loop 0.02 s later
    assert frames[4][1].timestamp == pytest.approx(1.0 + 0.04 / 2)
    assert key(plan.last) == key(frames[-1][1]) and plan.last.channel == "vcan1"
    assert plan.last_id_count == 9  # 0x10 three times per loop, the remapped 0x30 included


def test_an_hour_of_a_busy_bus_is_not_held_in_memory():
    hour = [Message(0x100 + i, 10) for i in range(5)]  # the soak's 500 frames/s
    plan = plans.schedule(Ecu(name="body", bus="vcan0", role="periodic", run_s=3600.0, messages=tuple(hour)), None)
    assert plan.count == 1_800_000
    tracemalloc.start()
    frames = plan.frames()
    for _ in range(20_000):
        next(frames)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 5 << 20  # an eager plan of 1.8 M frames takes about 0.6 GiB


def test_commands_plan_keeps_time_order_across_buses():
    cmds = [Commands(bus="vcan0", run_s=0.5, messages=(Message(0x6A0, 100),)),
            Commands(bus="vcan1", run_s=0.5, messages=(Message(0x6A1, 50),))]
    scenario = type("S", (), {"commands": cmds})()
    items = commands.plan(scenario)
    assert [t for t, *_ in items] == sorted(t for t, *_ in items)
    assert {b for _, b, *_ in items} == {"vcan0", "vcan1"} and len(items) == 5 + 10
