"""Runs one scenario from the orchestrator's side, in four steps: ready (the bridge's liveliness
token through the consumer's path, or a device's subscription to the tx keys when it announces
nothing; every echo ECU's token, the viewer's), captures (both sides, then the
token that tells the ECUs to go), traffic (the commands on the tx keys, fault steps, until every
ECU's done message), drain (until the bridge handled and published everything, the echoes
stopped). Then the analysis (canbench.analysis) writes metrics.json; the pytest checks read the
result."""
from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

from . import oracle, runkeys, security
from .analysis import RunResult, analyse, answer_ids, expected_answers
from .capture import CanCapture, ZenohCapture
from .commands import Commander
from .commands import plan as command_plan
from .faults import Injector
from .runkeys import rx_key, tx_key
from .scenario import Scenario

BRIDGE_READY_TIMEOUT_S = 60  # the default; a device started by hand gets longer (scripts/bench-run)
DRAIN_TIMEOUT_S = 5.0
# a device that announces nothing (no stats to say what it read) is drained once the capture holds
# what the ECUs sent and got nothing new for this long (or two publish periods)
DEVICE_QUIET_S = 0.5
# immediate mode's drained: nothing new read for this long (a frame still in the bridge's socket is
# in no counter: its last one read just after the stats said 1539 of 1540, seen once in the host lane)
IMMEDIATE_QUIET_S = 0.05
ECHO_STOP_TIMEOUT_S = 15
PROGRESS_EVERY_S = 2.0
TRAFFIC_SLACK_S = 30  # beyond duration_s before a run that does not finish is an error


def progress(line: str) -> None:
    """One line on the real stderr (pytest captures the rest), for long runs."""
    print(f"canbench: {line}", file=sys.__stderr__, flush=True)


def query_stats(session, prefix: str) -> dict | None:
    replies = [r for r in session.get(runkeys.bridge_stats(prefix)) if r.ok]
    return json.loads(replies[0].ok.payload.to_bytes()) if replies else None


def viewer_subscriptions(session) -> set[str]:
    """What the viewers on the network subscribe to (their stats queryables)."""
    out: set[str] = set()
    for reply in session.get(runkeys.VIEWER_STATS):
        if reply.ok:
            out |= set(json.loads(reply.ok.payload.to_bytes()).get("subscriptions", []))
    return out


class _Unchanged:
    """How long a counter has kept its value, as seen by successive looks (a drain's quiet time)."""

    def __init__(self) -> None:
        self.value: int | None = None
        self.since = 0.0

    def for_s(self, value: int) -> float:
        now = time.monotonic()
        if value != self.value:
            self.value, self.since = value, now
        return now - self.since


def _bounded(condition, timeout_s: float, what: str) -> bool:
    """A bounded wait whose timeout is no error: what is missing then, the checks report."""
    try:
        runkeys.wait_until(condition, timeout_s, what)
        return True
    except TimeoutError:
        return False


class Execution:
    """One run's sessions, the ECUs' done messages, the captures, the commander and the fault injector."""

    def __init__(self, scenario: Scenario, run_id: str, run_dir: Path, router: str, prefix: str,
                 consumer: str | None, project: str | None, device: str | None = None, announces: bool = True):
        self.scenario, self.run_id, self.run_dir, self.prefix = scenario, run_id, run_dir, prefix
        self.consumer, self.project = consumer or router, project
        self.device = device  # a device of your own under test (canbench.device), else the bench's bridge
        # False: a device that declares neither the bridge's liveliness token nor its stats queryable
        # (DEVICE_ANNOUNCES=0): ready once it subscribes to the tx keys, drained on the capture (_drain_unannounced)
        self.announces = announces
        self.session = runkeys.open_session(router)
        self.data = self.session if consumer in (None, router) else runkeys.open_session(consumer)
        self.done: dict[str, dict] = {}
        self.senders = {e.name for e in scenario.ecus} - {e.name for e in scenario.echoes}
        self.echo_names = {e.name for e in scenario.echoes}
        self.senders_done, self.echoes_done = threading.Event(), threading.Event()
        self.rx_keys = {rx_key(prefix, b, len(scenario.bus_names)) for b in scenario.bus_names}
        self.period_s = scenario.bridge.get("publish_period_ms", 0) / 1000
        self.deadline_s = scenario.duration_s + TRAFFIC_SLACK_S
        self.closing: list = []  # what stop_captures undoes, in reverse order
        self.commander: Commander | None = None
        self.injector: Injector | None = None
        self.bridge_stats: dict | None = None
        self.traffic_s = 0.0

    def _mark_done(self, name: str, summary: dict) -> None:
        self.done[name] = summary
        if self.senders <= set(self.done):
            self.senders_done.set()
        if self.echo_names <= set(self.done):
            self.echoes_done.set()

    def ready(self, wait_viewer: bool, bridge_timeout_s: float = BRIDGE_READY_TIMEOUT_S) -> None:
        """The data path is up end to end (the token seen through the consumer's path; a device that
        announces nothing: its subscription to every tx key, before the bench's own capture subscribes),
        the echoes are bound, and a recording viewer subscribes to the bridge's ROS 2 topic."""
        if self.announces:
            runkeys.wait_token(self.data, runkeys.bridges(self.prefix), bridge_timeout_s)
        else:
            n = len(self.scenario.bus_names)
            try:
                runkeys.wait_subscribed(self.data, [tx_key(self.prefix, b, n) for b in self.scenario.bus_names],
                                        bridge_timeout_s)
            except TimeoutError as missing:
                raise TimeoutError(f"{missing}: a device that announces nothing (DEVICE_ANNOUNCES=0) is ready once it "
                                   "subscribes to every bus's tx key") from None
        for e in self.scenario.echoes:
            runkeys.wait_token(self.session, runkeys.ecu_ready(self.run_id, e.name), BRIDGE_READY_TIMEOUT_S)
        if wait_viewer:
            runkeys.wait_token(self.session, runkeys.VIEWERS, BRIDGE_READY_TIMEOUT_S)
            wanted = set(runkeys.ros2_data_keys(self.scenario))
            runkeys.wait_until(lambda: wanted <= viewer_subscriptions(self.session), BRIDGE_READY_TIMEOUT_S,
                               "the viewer subscribed to the bridge's ROS 2 topic", step_s=0.1)

    def captures(self) -> None:
        """Both captures, the commander and the injector set up; then the token that starts the ECUs."""
        sub = self.session.declare_subscriber(
            runkeys.ecus_done(self.run_id),
            lambda s: self._mark_done(str(s.key_expr).split("/")[-2], json.loads(s.payload.to_bytes())))
        self.closing.append(sub.undeclare)
        can_capture = CanCapture(self.run_dir / "can.log", self.scenario.bus_names)
        self.closing.append(can_capture.stop)
        self.zenoh_capture = ZenohCapture(self.data, self.consumer, f"{self.prefix}/**", self.run_dir / "zenoh.tsv",
                                          runkeys.zenoh_capture_ready(self.run_id))
        self.closing.append(self.zenoh_capture.stop)
        if self.scenario.commands:
            self.commander = Commander(self.data, self.scenario, self.run_dir / "commands.tsv", self.prefix,
                                       fence=self.announces)
        if self.scenario.faults:
            if not self.project:
                raise RuntimeError("this scenario has fault steps: they need the compose project (BENCH_PROJECT) "
                                   "and Docker's socket, i.e. a run by make test / scripts/bench-run")
            self.injector = Injector(self.project, self.scenario.faults, self._ecu_killed,
                                     sample_bridge=self.device is None,
                                     device_dir=self.run_dir if self.device else None)
        token = self.session.liveliness().declare_token(runkeys.capture_ready(self.run_id))
        self.closing.append(token.undeclare)

    def _ecu_killed(self, name: str) -> None:
        """A fault step killed an ECU: what its send log holds is what it sent."""
        log = self.run_dir / f"ecu-{name}.sent.tsv"
        sent = sum(1 for line in open(log) if not line.startswith("#")) if log.exists() else 0
        self.done[name] = {"name": name, "killed": True, "sent": sent}
        if self.senders <= set(self.done):
            self.senders_done.set()

    def traffic(self) -> None:
        """Fault steps and commands run while the ECUs send; returns once every ECU said done."""
        started = time.monotonic()
        if self.injector:
            self.injector.start()
            self.closing.append(self.injector.stop)
        if self.commander:
            self.commander.start()
        # progress while the traffic runs; the wait itself is on the ECUs' done messages
        while not self.senders_done.wait(PROGRESS_EVERY_S) and time.monotonic() - started < self.deadline_s:
            # an ECU's done message can be lost while a fault step has the router down;
            # its summary file (written whole before the message) says the same
            for name in self.senders - set(self.done):
                summary_file = self.run_dir / f"ecu-{name}.json"
                if summary_file.exists():
                    self.done[name] = json.loads(summary_file.read_text())
            if self.senders <= set(self.done):  # also when there is no sender at all
                self.senders_done.set()
                break
            progress(f"{time.monotonic() - started:5.1f} s of up to {self.scenario.duration_s:g} s: "
                     f"{len(set(self.done) & self.senders)}/{len(self.senders)} ECUs done, "
                     f"{self.zenoh_capture.frames_on(self.rx_keys)} frames on Zenoh"
                     + (f", {self.commander.sent}/{len(self.commander.items)} commands put" if self.commander else ""))
        if not self.senders_done.is_set():
            raise TimeoutError(f"ECUs {sorted(self.senders - set(self.done))} did not finish within duration_s + "
                               f"{TRAFFIC_SLACK_S} s ({self.deadline_s:.0f} s); see their container logs")
        if self.commander:
            self.commander.join(max(0.0, self.deadline_s - (time.monotonic() - started)))
            if self.commander.is_alive():
                raise TimeoutError(f"commands not all put within duration_s + {TRAFFIC_SLACK_S} s "
                                   f"({self.deadline_s:.0f} s)")
            if self.commander.error:
                raise RuntimeError(f"putting commands failed: {self.commander.error}")
        if self.injector:
            self.injector.wait_faults(self.deadline_s)
        self.traffic_s = time.monotonic() - started

    def drain(self) -> None:
        """Bounded waits until the bridge handled every command and published what it read, the
        echoes stopped, and the samples in flight reached the capture; what is missing then is loss."""
        if self.commander and self.announces:
            self._drain_commands(self.commander.sent)
        elif self.commander:
            self._wait_answers()
        if self.echo_names:
            self.session.put(runkeys.ecu_stop(self.run_id), b"")
            if not self.echoes_done.wait(ECHO_STOP_TIMEOUT_S):
                raise TimeoutError(f"echo ECUs {sorted(self.echo_names - set(self.done))} did not stop within "
                                   f"{ECHO_STOP_TIMEOUT_S} s; see their container logs")

        if not self.announces:
            self._drain_unannounced()
            return
        # In batching mode the bridge reads its socket once per period: frames can wait there,
        # not yet in can_rx_frames. Drained = all it read is published and nothing new was read
        # for a whole period (immediate mode: for IMMEDIATE_QUIET_S).
        reading = _Unchanged()

        def drained() -> bool:
            stats = query_stats(self.session, self.prefix)
            if not stats:
                return False
            read = sum(b["can_rx_frames"] - b["filtered"] - b["rx_queue_drops"] for b in stats["buses"])
            # frames put with no connection (unrouted_frames; a device of your own may not say) are
            # worked off as surely as failed puts
            published = sum(b["published_frames"] + b["publish_errors"] + b.get("unrouted_frames", 0)
                            for b in stats["buses"])
            period_s = stats.get("publish_period_ms", 0) / 1000  # the bridge's own, whatever it was given
            return reading.for_s(read) >= max(2 * period_s, IMMEDIATE_QUIET_S) and published >= read
        _bounded(drained, DRAIN_TIMEOUT_S + 2 * max(self.period_s, 0.1), "the bridge to publish what it read")
        self.bridge_stats = query_stats(self.session, self.prefix)
        published = sum(b["published_frames"] for b in self.bridge_stats["buses"]) if self.bridge_stats else 0
        _bounded(lambda: self.zenoh_capture.frames_on(self.rx_keys) >= published, 2 + self.period_s,
                 "published frames to reach the capture")

    def _drain_commands(self, sent: int) -> None:
        def handled() -> bool:
            stats = query_stats(self.session, self.prefix)
            return stats is not None and sum(b["tx_frames"] + b["can_tx_errors"] + sum(b["tx_rejected"].values())
                                             for b in stats["buses"]) >= sent
        if _bounded(handled, DRAIN_TIMEOUT_S, "the bridge to write the commands to CAN"):
            self._wait_answers()

    def _wait_answers(self) -> None:
        """Until the echoes' answers to the commands reached the capture (bounded)."""
        ids = answer_ids(self.scenario)
        if not ids:
            return
        wanted = len(expected_answers(self.scenario, [(bus, oracle.Observed(frame, 0, 0))
                                                      for _, bus, _, frame in command_plan(self.scenario)]))
        keys = {rx_key(self.prefix, b, len(self.scenario.bus_names)): i for b, i in ids.items()}
        _bounded(lambda: self.zenoh_capture.frames_with_ids(keys) >= wanted, DRAIN_TIMEOUT_S + self.period_s,
                 "the echoes' answers to reach the capture")

    def _drain_unannounced(self) -> None:
        """A device with no stats: drained once the capture holds as many frames as the ECUs said they
        sent (a bridge forwards every frame of its bus but its own) and nothing new came for DEVICE_QUIET_S
        or two publish periods (commands still on their way to the bus, a duplicate); bounded like the
        stats' drain: what is missing then is loss (or a frame the device does not forward)."""
        expected = sum(int(summary.get("sent", 0)) for summary in self.done.values())
        quiet_s = max(2 * self.period_s, DEVICE_QUIET_S)
        arriving = _Unchanged()

        def drained() -> bool:
            frames = self.zenoh_capture.frames_on(self.rx_keys)
            return arriving.for_s(frames) >= quiet_s and frames >= expected
        _bounded(drained, DRAIN_TIMEOUT_S + 2 * max(self.period_s, 0.1) + quiet_s,
                 "the device to publish what the ECUs sent")

    def stop_captures(self) -> None:
        while self.closing:
            self.closing.pop()()

    def close(self) -> None:
        if self.data is not self.session:
            self.data.close()
        self.session.close()


def execute(scenario: Scenario, run_id: str, run_dir: Path, router: str, prefix: str = "vehicle/can",
            consumer: str | None = None, baseline: dict | None = None, project: str | None = None,
            wait_viewer: bool = False, ready_timeout_s: float = BRIDGE_READY_TIMEOUT_S,
            device: str | None = None, device_announces: bool = True) -> RunResult:
    """router: where the bench coordinates (ECUs, stats); consumer: where the capture and the
    commands connect (the router by default; a far router or the bridge itself by topology);
    project: the compose project, for fault steps; wait_viewer: a `canbench view` records the
    run (make test VIEWER=1), the traffic starts once its token says it subscribes; ready_timeout_s: how
    long the bridge's token may take (a device of your own started by hand: longer); device_announces:
    False for a device that declares neither the token nor the stats queryable (DEVICE_ANNOUNCES=0)."""
    if not device_announces and (device is None or wait_viewer):
        raise ValueError("device_announces=False is for a device of your own (DEVICE), without a viewer (it finds "
                         "bridges by their tokens, and its subscription would be taken for the device's)")
    run_dir.mkdir(parents=True, exist_ok=True)
    run = Execution(scenario, run_id, run_dir, router, prefix, consumer, project, device, device_announces)
    try:
        run.ready(wait_viewer, ready_timeout_s)
        try:
            run.captures()
            run.traffic()
            security.observe(run)  # the security scenario's probes (else nothing)
            run.drain()
        finally:
            run.stop_captures()
    finally:
        run.close()
    result = analyse(scenario, run_id, run_dir, prefix, run.done, run.bridge_stats, run.traffic_s, baseline,
                     run.injector.summary() if run.injector else None)
    result.metrics["device"] = device  # None: the bench's own bridge
    if device:
        result.metrics["device_announces"] = device_announces
    return result
