"""The consumer's side of Zenoh -> CAN: puts the scenario's commands (a trace or
generated messages) on the bridge's tx key with their timing, one frame per
sample as a vehicle application would, and logs each put (commands.tsv, the
send-log format of the ECUs) for the oracle. Each command carries the bridge's
attachment (docs/bridge.md): its sequence number on the bus and its source
time, the put time (less the entry's stamp_age_ms), which the bridge's deadline
(tx_max_age_ms) is judged on."""
from __future__ import annotations

import bisect
import json
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from . import periodic, restbus, wire
from .plans import SENT_LOG_HEADER, frame_of, sent_line, timed_plan
from .runkeys import bridge_stats, tx_key
from .scenario import Commands, Scenario
from .trace import read_replay

if TYPE_CHECKING:  # the analysis uses this module's plan without a Zenoh session
    import zenoh


def plan(scenario: Scenario) -> list[tuple[float, str, int, wire.Frame]]:
    """(offset s, bus, source line, frame) of every command, in time order."""
    return [item[:4] for item in _aged_plan(scenario)]


def _aged_plan(scenario: Scenario) -> list[tuple[float, str, int, wire.Frame, int]]:
    """plan(), each with how long before its put its source time is (ns, the entry's stamp_age_ms)."""
    out = []
    ages = scenario.stamp_ages_ms() if hasattr(scenario, "stamp_ages_ms") else []  # a plain plan: none
    for i, c in enumerate(scenario.commands):
        age_ns = int(ages[i] * 1e6) if i < len(ages) else 0
        out += [(m.timestamp, c.bus, line, frame_of(m), age_ns) for line, m in _messages(c)]
    out.sort(key=lambda item: item[0])
    return out


def stamp_ages_ns(scenario: Scenario) -> dict[tuple[str, int, bool], int]:
    """(bus, id, extended) -> how long before its put a command's source time is (ns), for the commands
    of entries with a stamp_age_ms (their ids are theirs alone, the schema says)."""
    return {(bus, f.can_id, f.extended): age_ns for _, bus, _, f, age_ns in _aged_plan(scenario) if age_ns}


def stale_at_put(scenario: Scenario) -> set[tuple[str, int, bool]]:
    """(bus, id, extended) of the commands stamped older than the bridge's deadline when put (an
    entry's stamp_age_ms over tx_max_age_ms): the bridge must refuse every one; none with the deadline off."""
    deadline_ns = scenario.tx_max_age_ms * 1_000_000
    return {k for k, age_ns in stamp_ages_ns(scenario).items() if age_ns > deadline_ns} if deadline_ns else set()


def explained_refusals(bus: str, commands: list, tx, stale: set[tuple[str, int, bool]]) -> tuple[int, list]:
    """What explains the bridge's stale refusals on one bus, apart from a late link: how many commands
    stamped too old when put never reached the bus, and the commands lost inside fault windows (those
    stamped too old counted apart)."""
    def key(o):
        return (bus, o.frame.can_id, o.frame.extended)
    reached = {id(s) for s, _ in tx.matched} | {id(s) for s, _, _ in tx.corrupted}
    stamped_refused = sum(1 for s in commands if key(s) in stale and id(s) not in reached)
    return stamped_refused, [o for o in tx.lost_in_faults if key(o) not in stale]


def delivered_late(bus: str, lost: list, matched: list, ages_ns: dict, deadline_ns: int,
                   arrived_by_ns: int | None = None) -> list[tuple]:
    """(command, upper bound of its age at the bridge in ms, "bus" or "fence": which bound showed it) for
    each lost command a late link explains:
    every command of its id put after it (one publisher, one QoS: none can overtake it) reached the bus
    more than the deadline after the lost one's source time, so the lost one reached the bridge at least as late,
    as far as the bench can see: stale, and refused as the bridge must. A stream's last commands, put after
    the last of the bus's commands that reached the bus, have no such command: for them arrived_by_ns (the
    commander's fence: by then the bridge counted every command of the bus) is the bound. Oldest first. A
    lost command with neither bound is not explained."""
    delivered: dict[tuple[int, bool], list[tuple[int, int]]] = {}
    for s, r in matched:
        delivered.setdefault((s.frame.can_id, s.frame.extended), []).append((s.index, r.t_ns))
    last_reached = max((s.index for s, _ in matched), default=-1)
    # per id, in put order: the earliest bus time of any command put at or after each position
    # (one bisect per lost command, not a scan: a lossy bridge may lose thousands)
    by_id = {}
    for key, pairs in delivered.items():
        pairs.sort()
        earliest = [t for _, t in pairs]
        for k in range(len(earliest) - 2, -1, -1):
            earliest[k] = min(earliest[k], earliest[k + 1])
        by_id[key] = ([i for i, _ in pairs], earliest)
    out = []
    for o in lost:
        indices, earliest = by_id.get((o.frame.can_id, o.frame.extended), ([], []))
        k = bisect.bisect_right(indices, o.index)
        if k < len(indices):
            bound, shown_by = earliest[k], "bus"
        elif arrived_by_ns and o.index > last_reached:  # the fence bounds only the stream's tail
            bound, shown_by = arrived_by_ns, "fence"
        else:
            continue
        source_ns = o.t_ns - ages_ns.get((bus, o.frame.can_id, o.frame.extended), 0)
        if bound - source_ns > deadline_ns:
            out.append((o, round((bound - source_ns) / 1e6, 3), shown_by))
    return sorted(out, key=lambda item: -item[1])


def _messages(c: Commands):
    if c.signal_plan is not None:  # commands in signals, encoded with cantools
        return restbus.command_frames(c)
    if c.trace is not None:
        frames, t0 = read_replay(c.trace, c.interface)  # an interface keeps its timing in the trace
        return timed_plan(frames, c.speed, 1, c.start_offset_s, c.bus, {}, t0).frames()
    return ((0, m) for m in periodic.periodic_frames(c.messages, c.run_s, c.start_offset_s, c.bus))


ARRIVAL_FENCE_TIMEOUT_S = 2.0  # a bridge that never counts every command (a lost sample) leaves no fence
ARRIVAL_FENCE_STEP_S = 0.005


def arrivals_path(commands_log: Path) -> Path:
    """Where the commander writes, per bus, by when every command had reached the bridge."""
    return commands_log.with_name("commands-arrived.json")


def read_arrivals(commands_log: Path) -> dict[str, int]:
    """bus -> wall time (ns) by which every command of that bus had reached the bridge (none: {})."""
    path = arrivals_path(commands_log)
    if not path.exists():
        return {}
    return {bus: a["all_arrived_by_ns"] for bus, a in json.loads(path.read_text()).items()
            if a.get("all_arrived_by_ns")}


def _tx_samples(reply) -> dict[str, int]:
    """bus -> tx_samples of one stats reply; {} for an error, an empty or a foreign reply."""
    try:
        buses = json.loads(bytes(reply.ok.payload.to_bytes()))["buses"] if reply.ok else []
        return {b["bus"]: int(b["tx_samples"]) for b in buses}
    except (ValueError, KeyError, TypeError):
        return {}


class Commander(threading.Thread):
    """Publishes the plan in a thread; .error holds what stopped it early, if anything. After the
    last put it fences the stream: per bus, the receipt time of the first stats reply in which the
    bridge counts every command put on it (tx_samples), an upper bound on when each one reached the
    bridge (commands-arrived.json; delivered_late's bound for a stream's last commands). fence=False:
    a device with no stats queryable (DEVICE_ANNOUNCES=0), no fence and no file."""

    def __init__(self, session: zenoh.Session, scenario: Scenario, log_path: Path, prefix: str = "vehicle/can",
                 fence: bool = True):
        super().__init__(name="commander", daemon=True)
        self.items = _aged_plan(scenario)
        self.log_path = log_path
        self.session, self.prefix = session, prefix
        buses = scenario.bus_names
        self.publishers = {b: session.declare_publisher(tx_key(prefix, b, len(buses))) for b in buses}
        self.sent = 0
        self.sent_per_bus = dict.fromkeys(buses, 0)
        self.error: BaseException | None = None
        self.fence = fence

    def run(self) -> None:
        try:
            with open(self.log_path, "w") as log:
                log.write(SENT_LOG_HEADER)
                start = time.monotonic()
                seq = dict.fromkeys(self.publishers, 0)
                for offset, bus, line, frame, age_ns in self.items:
                    delay = start + offset - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)  # pacing to the scenario's timing, not synchronisation
                    now_ns = time.time_ns()
                    # the source time the bridge's deadline judges: the put time, as a sender stamps its command
                    attachment = wire.encode_attachment(seq[bus], [now_ns - age_ns])
                    seq[bus] += 1
                    self.publishers[bus].put(wire.encode(frame), attachment=attachment)
                    self.sent += 1
                    self.sent_per_bus[bus] += 1
                    log.write(sent_line(line, now_ns, frame, bus))
            if self.fence:
                self._fence()
        except BaseException as e:  # reported by the orchestrator, never lost in a thread
            self.error = e
        finally:
            for pub in self.publishers.values():
                pub.undeclare()

    def _fence(self) -> None:
        """Writes commands-arrived.json: per bus with commands, when the bridge's stats first counted
        all of them (the reply's receipt time; None if they never did within the fence's timeout)."""
        waiting = {bus for bus, n in self.sent_per_bus.items() if n}
        arrived: dict[str, int | None] = dict.fromkeys(waiting)
        deadline = time.monotonic() + ARRIVAL_FENCE_TIMEOUT_S
        while waiting and (left_s := deadline - time.monotonic()) > 0:
            for reply in self.session.get(bridge_stats(self.prefix), timeout=left_s):
                now_ns = time.time_ns()
                for bus, samples in _tx_samples(reply).items():
                    if bus in waiting and samples >= self.sent_per_bus[bus]:
                        arrived[bus] = now_ns
                        waiting.discard(bus)
            if waiting:
                time.sleep(ARRIVAL_FENCE_STEP_S)  # polling the bridge's counters, bounded by the deadline
        arrivals_path(self.log_path).write_text(json.dumps(
            {bus: {"sent": self.sent_per_bus[bus], "all_arrived_by_ns": t} for bus, t in arrived.items()}, indent=1))
