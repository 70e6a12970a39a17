"""The consumer's side of Zenoh -> CAN: puts the scenario's commands (a trace or
generated messages) on the bridge's tx key with their timing, one frame per
sample as a vehicle application would, and logs each put (commands.tsv, the
send-log format of the ECUs) for the oracle."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import zenoh

from . import periodic, wire
from .plans import SENT_LOG_HEADER, frame_of, sent_line, timed_plan
from .runkeys import tx_key
from .scenario import Commands, Scenario
from .trace import read_trace


def plan(scenario: Scenario) -> list[tuple[float, str, int, wire.Frame]]:
    """(offset s, bus, source line, frame) of every command, in time order."""
    out = []
    for c in scenario.commands:
        out += [(m.timestamp, c.bus, line, frame_of(m)) for line, m in _messages(c)]
    out.sort(key=lambda item: item[0])
    return out


def _messages(c: Commands):
    if c.trace is not None:
        return timed_plan(read_trace(c.trace, None), c.speed, 1, c.start_offset_s, c.bus, {}).frames()
    return ((0, m) for m in periodic.periodic_frames(c.messages, c.run_s, c.start_offset_s, c.bus))


class Commander(threading.Thread):
    """Publishes the plan in a thread; .error holds what stopped it early, if anything."""

    def __init__(self, session: zenoh.Session, scenario: Scenario, log_path: Path, prefix: str = "vehicle/can"):
        super().__init__(name="commander", daemon=True)
        self.items = plan(scenario)
        self.log_path = log_path
        buses = scenario.bus_names
        self.publishers = {b: session.declare_publisher(tx_key(prefix, b, len(buses))) for b in buses}
        self.sent = 0
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            with open(self.log_path, "w") as log:
                log.write(SENT_LOG_HEADER)
                start = time.monotonic()
                for offset, bus, line, frame in self.items:
                    delay = start + offset - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)  # pacing to the scenario's timing, not synchronisation
                    now_ns = time.time_ns()
                    self.publishers[bus].put(wire.encode(frame))
                    self.sent += 1
                    log.write(sent_line(line, now_ns, frame, bus))
        except BaseException as e:  # reported by the orchestrator, never lost in a thread
            self.error = e
        finally:
            for pub in self.publishers.values():
                pub.undeclare()
