"""What an ECU or the commander sends, as a plan made lazily (an hour of a busy bus held as
can.Message objects is gigabytes): a trace's frames with speed, loops, offset and id remap, or
the periodic engine's frames; and the send log both write (ecu-<name>.sent.tsv, commands.tsv:
trace line, send time, the frame in candump form), which the oracle reads back."""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can

from . import periodic, restbus
from .scenario import Ecu, Scenario
from .trace import read_replay
from .trace_frames import TraceFrames
from .wire import Frame


@dataclass(frozen=True)
class Plan:
    """What an ECU sends, in send order. The frames are made as they are sent (frames() gives a
    fresh iterator each call): an hour at 500 frames/s held as can.Message objects is ~0.6 GiB."""
    frames: Callable[[], Iterator[tuple[int, can.Message]]]  # (trace line, message); generated: line 0
    count: int
    last: can.Message | None
    last_id_count: int  # frames with the last frame's id and id format: the own copies to wait for


def schedule(ecu: Ecu, scenario: Scenario) -> Plan:
    """The ECU's plan with speed, loops, offset and id remap applied."""
    if ecu.role == "restbus":
        return restbus.restbus_plan(ecu)
    if ecu.role == "periodic":
        msgs, run_s, start, bus = ecu.messages, ecu.run_s, ecu.start_offset_s, ecu.bus
        last = periodic.periodic_last(msgs, run_s, start, bus)
        return Plan(frames=lambda: ((0, m) for m in periodic.periodic_frames(msgs, run_s, start, bus)),
                    count=sum(periodic.periodic_count(m, run_s) for m in msgs), last=last,
                    last_id_count=sum(periodic.periodic_count(m, run_s) for m in msgs
                                      if last and (m.can_id, m.extended) == (last.arbitration_id,
                                                                             last.is_extended_id)))
    frames, t0 = read_replay(ecu.trace, ecu.interface) if ecu.trace else (TraceFrames(), None)
    return timed_plan(frames, ecu.speed, ecu.loops, ecu.start_offset_s, ecu.bus, ecu.id_remap, t0)


def timed_plan(frames: TraceFrames, speed: float, loops: int, start_offset_s: float, bus: str,
               id_remap: dict[int, int], t0: float | None = None) -> Plan:
    """A trace's frames looped `loops` times at `speed`; t0: the time they are sent relative to
    (default their first: an interface of a trace, the trace's first). Each Message is made from
    the frames' columns as it is sent."""
    if not frames:
        return Plan(frames=lambda: iter(()), count=0, last=None, last_id_count=0)
    first_ns = frames.t_ns(0)
    t0_ns = first_ns if t0 is None else round(t0 * 1e9)
    span_s = (frames.t_ns(len(frames) - 1) - first_ns) / 1e9  # a loop: the frames' own span and first gap
    period = span_s + ((frames.t_ns(1) - first_ns) / 1e9 if len(frames) > 1 else 0.001)

    def offset_s(loop: int) -> float:  # a frame goes at start_offset_s + (t - t0 + loop * period) / speed
        return start_offset_s + loop * period / speed

    def sent() -> Iterator[tuple[int, can.Message]]:
        for loop in range(loops):
            yield from frames.sent(t0_ns, offset_s(loop), 1 / speed, id_remap, bus)

    last_at = len(frames) - 1
    can_id = frames.key(last_at)[0]
    last = frames.message(last_at, offset_s(loops - 1) + (frames.t_ns(last_at) - t0_ns) / 1e9 / speed,
                          id_remap.get(can_id, can_id), bus)
    wanted = (last.arbitration_id, last.is_extended_id)
    per_loop = sum(n for (can_id, extended), n in Counter(frames.keys()).items()
                   if (id_remap.get(can_id, can_id), extended) == wanted)
    return Plan(frames=sent, count=loops * len(frames), last=last, last_id_count=loops * per_loop)


def frame_of(msg: can.Message) -> Frame:
    return Frame(msg.arbitration_id, msg.dlc, b"" if msg.is_remote_frame else bytes(msg.data),
                 msg.is_extended_id, msg.is_remote_frame)


SENT_LOG_HEADER = "# trace_line\tsend_time_ns\tframe (candump form)\n"


def sent_line(line: int, t_ns: int, frame: Frame, bus: str) -> str:
    """One send-log line: source line (0: generated), send time (ns), the frame in candump form."""
    return f"{line}\t{t_ns}\t{frame.candump(bus)}\n"
