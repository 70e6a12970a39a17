"""An emulated ECU, one of five roles:
  replay    its trace with the recorded timing (python-can MessageSync)
  periodic  generated messages (counter + checksum) for run_s
  restbus   every cyclic message of a DBC node, encoded from signals (canbench.restbus), for
            run_s: paced and reported like a replay
  echo      answers frames with ids in echo_ids, canfdtest style (id + offset,
            every data byte + 1), until the orchestrator says stop
  responder answers DBC messages by its rules (on X send Y with Y.signal = f(X.signal)), until
            the orchestrator says stop
Each logs what it sent and when (ecu-<name>.sent.tsv, frames in candump form)
and reports its own timing fidelity so a verdict never blames the bridge for
emulator jitter.

The ECU waits for the run's capture to be ready (a liveliness token the
orchestrator declares), runs its role, then publishes its summary on
bench/runs/<run-id>/ecus/<name>/done and exits."""
from __future__ import annotations

import itertools
import json
import select
import statistics
import sys
import threading
import time
from array import array
from collections.abc import Callable
from pathlib import Path

import can

from . import restbus, runkeys
from .dbc import message_of
from .j1939 import addressed, group_filters, group_of
from .plans import SENT_LOG_HEADER, frame_of, schedule, sent_line
from .scenario import Ecu, Scenario
from .stats import percentile
from .wire import Frame

SEND_TIMEOUT_S = 5.0
ECHO_POLL_S = 0.05  # how often the echo loop looks at its stop flag while the bus is quiet


def fidelity(errors_ms) -> dict:
    return {"p50": round(percentile(errors_ms, 0.5) or 0.0, 3), "p95": round(percentile(errors_ms, 0.95) or 0.0, 3),
            "p99": round(percentile(errors_ms, 0.99) or 0.0, 3),
            "max": round(max(errors_ms, default=0.0), 3),
            "mean": round(statistics.fmean(errors_ms), 3) if errors_ms else 0.0}


class OwnLateness:
    """The part of each frame's send error that is the emulator's own: late beyond the moment the
    previous send would have ended had only the bus held it up (its wait for a full bus, as a real
    sender waits on a saturated bus: not the emulator's fault, plus an ordinary send's cost), or by
    what the previous frame passes on: its own lateness less the trace's spacing and that excused
    time. A ready send that took longer than READY_SEND_MAX_S was held up by the machine (a stopped
    or descheduled process): the frames due meanwhile are late by the ECU's doing (excusing every
    send's whole duration read 3 x 100 ms stopped as p95 1.2 ms when the stops landed inside sends)."""

    READY_SEND_MAX_S = 0.001  # a send the bus is ready for takes 10-50 us in Python

    def __init__(self):
        self.errors_ms = array("d")  # 8 bytes per frame: an hour's worth stays small
        self._freed = 0.0  # when the previous send would have ended, held up only by the bus
        self._passed_on = 0.0  # s: the own lateness the previous frame passes on to those behind it
        self._previous_due = 0.0

    def sent(self, due: float, at: float, bus_wait: float, done: float) -> None:
        """A frame due at `due` whose send began at `at` and ended at `done`, of which `bus_wait`
        was spent waiting for a full bus (seconds on one monotonic clock)."""
        late = max(at - max(due, self._freed), self._passed_on - max(0.0, due - self._previous_due))
        self.errors_ms.append(late * 1000)
        excused = bus_wait + min(done - at - bus_wait, self.READY_SEND_MAX_S)
        self._freed = at + excused
        self._passed_on, self._previous_due = late - excused, due


def replay(ecu: Ecu, scenario: Scenario, run_dir: Path) -> dict:
    plan = schedule(ecu, scenario)
    sent_log = run_dir / f"ecu-{ecu.name}.sent.tsv"
    errors_ms = array("d")  # 8 bytes per frame: an hour's worth stays small
    own = OwnLateness()
    # line-buffered and written just before each send: an ECU killed by a fault step leaves a
    # log that accounts for every frame it put on the bus (the oracle relies on it)
    # our own copies of the last frame's id come back (CAN_RAW_RECV_OWN_MSGS, filtered to that id):
    # the ECU says done only once the bus has carried everything it sent
    last = plan.last
    mine = [{"can_id": last.arbitration_id, "can_mask": 0x1FFFFFFF, "extended": last.is_extended_id}] if last else None
    with can.Bus(interface="socketcan", channel=ecu.bus, receive_own_messages=bool(mine), can_filters=mine) as bus, \
            open(sent_log, "w", buffering=1) as log:
        log.write(SENT_LOG_HEADER)
        timed, to_sync = itertools.tee(plan.frames())  # MessageSync paces one copy, the log reads the other
        first = next(plan.frames(), None)
        # MessageSync times messages relative to the first one: wait out the first offset here
        first_s = first[1].timestamp if first else 0.0
        time.sleep(first_s)  # the scenario's start offset (pacing, not synchronisation)
        start = time.perf_counter() - first_s
        wall0 = time.time_ns() - int(start * 1e9)
        seen = 0
        # MessageSync sleeps until each message's offset: the recorded timing
        synced_messages = can.MessageSync((m for _, m in to_sync), timestamps=True, skip=3600)
        for (line, msg), synced in zip(timed, synced_messages, strict=True):
            now = time.perf_counter()
            log.write(sent_line(line, wall0 + int(now * 1e9), frame_of(msg), ecu.bus))
            bus_wait = _send(bus, synced)
            errors_ms.append((now - start - msg.timestamp) * 1000)
            own.sent(due=start + msg.timestamp, at=now, bus_wait=bus_wait, done=time.perf_counter())
            if last is not None:  # read the copies as they come: a long run would overflow the socket
                seen += _own_copies(bus, last, timeout=0.0)
        if last is not None:
            _wait_own_copies(bus, last, plan.last_id_count, seen)
    return {"name": ecu.name, "role": ecu.role, "bus": ecu.bus, "trace": str(ecu.trace) if ecu.trace else None,
            **({"interface": ecu.interface} if ecu.interface else {}), "sent": plan.count,
            "fidelity_ms": fidelity(errors_ms), "own_send_error_ms": fidelity(own.errors_ms)}


def _send(bus: can.BusABC, msg: can.Message) -> float:
    """Sends msg and returns how long a full bus held it (s): 0.0 when the socket took it at once.
    A busy bus makes a sender wait, as on a real one (a hub paces its senders by not reading them)."""
    ready = bool(select.select([], [bus], [], 0)[1])
    began = time.perf_counter()
    bus.send(msg, timeout=SEND_TIMEOUT_S)
    return 0.0 if ready else time.perf_counter() - began


def _own_copies(bus: can.BusABC, last: can.Message, timeout: float) -> int:
    """Own copies of the last frame's id read now (at most one wait of `timeout`)."""
    seen = 0
    while (msg := bus.recv(timeout=timeout)) is not None:
        seen += msg.arbitration_id == last.arbitration_id and not msg.is_rx
        timeout = 0.0
    return seen


def _wait_own_copies(bus: can.BusABC, last: can.Message, expected: int, seen: int) -> None:
    deadline = time.monotonic() + SEND_TIMEOUT_S
    while seen < expected:
        msg = bus.recv(timeout=max(0.0, deadline - time.monotonic()))
        if msg is None:
            raise TimeoutError(f"the bus carried {seen} of the {expected} frames with id "
                               f"{last.arbitration_id:X} this ECU sent (within {SEND_TIMEOUT_S} s)")
        seen += msg.arbitration_id == last.arbitration_id and not msg.is_rx


def _answer_requests(ecu: Ecu, filters: list[dict], run_dir: Path, stop: threading.Event, session, run_id: str,
                     timeout_s: float, is_request: Callable[[can.Message], bool],
                     answer_of: Callable[[can.Message], can.Message | None]) -> tuple[int, int, list[float]]:
    """The answering roles' loop (echo, responder): bound to the bus before it says ready (a
    liveliness token the orchestrator waits for), it answers every data frame is_request takes
    with answer_of's frame (None: counted, not answered), logged as sent, until stop is set and
    the socket holds nothing more. Returns (requests received, answers sent, turnaround in ms)."""
    sent_log = run_dir / f"ecu-{ecu.name}.sent.tsv"
    received = answered = 0
    turnaround_ms: list[float] = []
    with can.Bus(interface="socketcan", channel=ecu.bus, can_filters=filters) as bus, \
            open(sent_log, "w", buffering=1) as log:
        log.write(SENT_LOG_HEADER)
        ready = session.liveliness().declare_token(runkeys.ecu_ready(run_id, ecu.name))
        runkeys.wait_token(session, runkeys.capture_ready(run_id), timeout_s)
        while True:
            msg = bus.recv(timeout=ECHO_POLL_S)
            if msg is None:
                if stop.is_set():
                    break
                continue
            if msg.is_remote_frame or msg.is_error_frame or not is_request(msg):
                continue
            received += 1
            answer = answer_of(msg)
            if answer is None:
                continue
            now_ns = time.time_ns()
            log.write(sent_line(0, now_ns, frame_of(answer), ecu.bus))
            bus.send(answer, timeout=SEND_TIMEOUT_S)
            answered += 1
            turnaround_ms.append((now_ns / 1e9 - msg.timestamp) * 1000)
        ready.undeclare()
    return received, answered, turnaround_ms


def echo(ecu: Ecu, run_dir: Path, stop: threading.Event, session, run_id: str, timeout_s: float) -> dict:
    """Answers every request (ids in echo_ids) until stop is set and the socket holds nothing more."""
    filters = [{"can_id": i, "can_mask": 0x1FFFFFFF if i > 0x7FF else 0x7FF, "extended": i > 0x7FF}
               for i in sorted(ecu.echo_ids)]

    def answer_of(msg: can.Message) -> can.Message:
        can_id, data = ecu.answer(msg.arbitration_id, bytes(msg.data))
        return can.Message(arbitration_id=can_id, is_extended_id=msg.is_extended_id, data=data,
                           dlc=msg.dlc, channel=ecu.bus)

    received, answered, turnaround_ms = _answer_requests(
        ecu, filters, run_dir, stop, session, run_id, timeout_s,
        lambda msg: msg.arbitration_id in ecu.echo_ids, answer_of)
    return {"name": ecu.name, "role": ecu.role, "bus": ecu.bus, "received": received, "sent": answered,
            "turnaround_ms": fidelity(turnaround_ms)}


def request_routes(rules) -> tuple[list[dict], Callable[[can.Message], restbus.Rule | None]]:
    """The responder's socket filters (python-can's) and the rule of a received frame: a request
    of its DBC id, or of a J1939 group the DBC reads from any source (dbc.group_read), at any
    priority, addressed to the DBC id's destination or to global (j1939.addressed)."""
    by_id = {(r.on.frame_id, r.on.is_extended_frame): r for r in rules}
    by_group = {r.group: r for r in rules if r.group is not None}
    filters = []
    for (i, ext), r in sorted(by_id.items()):
        pairs = group_filters(i) if r.group is not None else [(i, 0x1FFFFFFF if ext else 0x7FF)]
        filters += [{"can_id": can_id, "can_mask": mask, "extended": ext} for can_id, mask in pairs]

    def rule_of(msg: can.Message) -> restbus.Rule | None:
        rule = by_id.get((msg.arbitration_id, msg.is_extended_id))
        if rule is None and msg.is_extended_id and by_group:
            rule = by_group.get(group_of(msg.arbitration_id))  # type: ignore[arg-type]
            frame = Frame(msg.arbitration_id, msg.dlc, b"", True)
            if rule is not None and not (addressed(rule.on.frame_id, msg.arbitration_id)
                                         and message_of(rule.db, frame) is rule.on):  # not another message's id
                rule = None
        return rule
    return filters, rule_of


def responder(ecu: Ecu, run_dir: Path, stop: threading.Event, session, run_id: str, timeout_s: float) -> dict:
    """Answers each frame of a rule's request message with the rule's answer (canbench.restbus.Rule),
    until stop is set and the socket holds nothing more, as echo."""
    filters, rule_of = request_routes(ecu.rules)
    answers: dict[tuple[int, bool], int] = {}
    unanswerable: list[str] = []  # the first reason, then a count

    def answer_of(msg: can.Message) -> can.Message | None:
        rule = rule_of(msg)
        assert rule is not None  # asked only for frames rule_of knows
        key = (rule.on.frame_id, rule.on.is_extended_frame)  # the answer's counter counts the rule's answers
        try:
            message, data = rule.answer(bytes(msg.data), answers.get(key, 0))
        except restbus.UndecodableRequest:  # counted (received - answered - unanswerable), not answered
            return None
        except restbus.Unanswerable as e:
            unanswerable.append(str(e) if not unanswerable else "")
            return None
        answers[key] = answers.get(key, 0) + 1
        return can.Message(arbitration_id=message.frame_id, is_extended_id=message.is_extended_frame,
                           data=data, dlc=message.length, channel=ecu.bus)

    received, answered, turnaround_ms = _answer_requests(
        ecu, filters, run_dir, stop, session, run_id, timeout_s,
        lambda msg: rule_of(msg) is not None, answer_of)
    # every request is answered, undecodable or unanswerable (a failed send ends the role)
    summary = {"name": ecu.name, "role": ecu.role, "bus": ecu.bus, "received": received, "sent": answered,
               "undecodable": received - answered - len(unanswerable), "unanswerable": len(unanswerable),
               "turnaround_ms": fidelity(turnaround_ms)}
    if unanswerable:
        summary["unanswerable_first"] = unanswerable[0]
    return summary


def run(scenario: Scenario, name: str, run_id: str, run_dir: Path, router: str, timeout_s: float) -> dict:
    ecu = next((e for e in scenario.ecus if e.name == name), None)
    if ecu is None:
        raise SystemExit(f"{scenario.path}: no ECU named {name!r}")
    session = runkeys.open_session(router)
    try:
        stop = threading.Event()
        stop_sub = session.declare_subscriber(runkeys.ecu_stop(run_id), lambda _sample: stop.set())
        if ecu.role == "echo":
            summary = echo(ecu, run_dir, stop, session, run_id, timeout_s)
        elif ecu.role == "responder":
            summary = responder(ecu, run_dir, stop, session, run_id, timeout_s)
        else:
            if ecu.left_out:  # a restbus node's CAN FD messages: said, never truncated
                print(f"ecu {ecu.name}: {ecu.dbc_node}'s messages left out: {', '.join(ecu.left_out)}", file=sys.stderr)
            runkeys.wait_token(session, runkeys.capture_ready(run_id), timeout_s)
            summary = replay(ecu, scenario, run_dir)
            if ecu.left_out:
                summary["left_out"] = list(ecu.left_out)
        stop_sub.undeclare()
        tmp = run_dir / f".ecu-{ecu.name}.json.tmp"
        tmp.write_text(json.dumps(summary, indent=2))
        tmp.replace(run_dir / f"ecu-{ecu.name}.json")  # whole or absent: the orchestrator may read it any time
        session.put(runkeys.ecu_done(run_id, name), json.dumps(summary))
        return summary
    finally:
        session.close()
