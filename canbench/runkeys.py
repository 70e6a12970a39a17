"""Zenoh keys the bench uses to coordinate a run between containers (never
sleeps: each side waits for an explicit signal), and the client session
every bench process opens: explicit endpoint, multicast scouting off."""
from __future__ import annotations

import json
import os
import threading
import time

import zenoh

from . import ros2


def rx_key(prefix: str, bus: str, bus_count: int) -> str:
    """Where a bridge publishes a bus's frames: <prefix>/rx for one bus, <prefix>/<bus>/rx for several."""
    return f"{prefix}/rx" if bus_count == 1 else f"{prefix}/{bus}/rx"


def tx_key(prefix: str, bus: str, bus_count: int) -> str:
    """Where a bridge takes a bus's commands (the same shape as rx_key)."""
    return f"{prefix}/tx" if bus_count == 1 else f"{prefix}/{bus}/tx"


def bridges(prefix: str) -> str:
    """The bridges' liveliness tokens: <prefix>/bridges/<name>/<bus>/<mode>."""
    return f"{prefix}/bridges/**"


def bridge_stats(prefix: str, name: str = "*") -> str:
    """A bridge's stats queryable."""
    return f"{prefix}/bridges/{name}/stats"


def ecus_done(run_id: str) -> str:
    """Every ECU's done message (ecu_done: one of them)."""
    return f"bench/runs/{run_id}/ecus/*/done"


def ros2_data_keys(scenario) -> list[str]:
    """The data keys of the bridge's ROS 2 output (bridge.ros2_topic), one per bus."""
    topic = scenario.bridge.get("ros2_topic")
    if not topic:
        return []
    topics = [topic] if len(scenario.bus_names) == 1 else [f"{topic}/{b}" for b in scenario.bus_names]
    frame = "can_msgs/msg/Frame"
    # Humble's keys (bridge.ros2_humble) carry TypeHashNotSupported where later ones carry the hash
    hash_ = "TypeHashNotSupported" if scenario.bridge.get("ros2_humble") else ros2.type_hash(frame)
    return [ros2.data_key(scenario.bridge.get("ros2_domain", 0), t, frame, hash_) for t in topics]


VIEWERS = "canbench/viewers/*"  # a canbench view's liveliness token
VIEWER_STATS = "canbench/viewers/*/stats"  # its stats queryable: what it subscribes to


def capture_ready(run_id: str) -> str:
    return f"bench/runs/{run_id}/capture-ready"


def ecu_done(run_id: str, name: str) -> str:
    return f"bench/runs/{run_id}/ecus/{name}/done"


def zenoh_capture_ready(run_id: str) -> str:
    """Liveliness token of zn-capture, declared once its subscriber is in place."""
    return f"bench/runs/{run_id}/capture/zenoh"


def ecu_ready(run_id: str, name: str) -> str:
    """Liveliness token of an echo ECU bound to its bus, ready to answer."""
    return f"bench/runs/{run_id}/ecus/{name}/ready"


def ecu_stop(run_id: str) -> str:
    """Put by the orchestrator when echo ECUs may stop answering."""
    return f"bench/runs/{run_id}/stop"


def base_config() -> zenoh.Config:
    """$ZENOH_CONFIG (a Zenoh JSON5 file: the service's identity, TLS; docs/access-control.md)
    when set and not empty, else zenoh's defaults; the caller's settings go on top."""
    path = os.environ.get("ZENOH_CONFIG")
    return zenoh.Config.from_file(path) if path else zenoh.Config()


def open_session(endpoint: str, wait: bool = True, wait_s: float | None = None) -> zenoh.Session:
    """wait: for the router rather than fail (at most wait_s, else for ever), and back within a
    second of a router restart; without, zenoh's defaults (the tests: a router they started is
    already listening)."""
    conf = base_config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if wait:
        conf.insert_json5("connect/timeout_ms", str(int(wait_s * 1000)) if wait_s is not None else "-1")
        # like the bridge's own retry (fault steps restart the router)
        conf.insert_json5("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}")
    return zenoh.open(conf)


def wait_token(session: zenoh.Session, key: str, timeout_s: float) -> None:
    """Blocks until a liveliness token on key exists (subscriber + initial query, no polling)."""
    seen = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        if not seen.wait(timeout_s):
            raise TimeoutError(f"no liveliness token on {key} after {timeout_s:.0f} s")
    finally:
        sub.undeclare()


def _matching(status: object) -> bool:
    """A MatchingStatus's answer (zenoh-python 1.10's stub says a bool; the object has .matching)."""
    return bool(getattr(status, "matching", status))


def wait_subscribed(session: zenoh.Session, keys: list[str], timeout_s: float) -> None:
    """Blocks until every key has a subscriber somewhere (a publisher's matching status, pushed by
    the router: no polling). Nothing is put on them."""
    deadline = time.monotonic() + timeout_s
    for key in keys:
        seen = threading.Event()

        def on_status(status: object, seen: threading.Event = seen) -> None:
            if _matching(status):
                seen.set()
        pub = session.declare_publisher(key)
        try:
            listener = pub.declare_matching_listener(on_status)
            try:
                if not (_matching(pub.matching_status) or seen.wait(max(0.0, deadline - time.monotonic()))):
                    raise TimeoutError(f"no subscriber on {key} after {timeout_s:g} s")
            finally:
                listener.undeclare()
        finally:
            pub.undeclare()


def wait_until(condition, timeout_s: float, what: str, step_s: float = 0.02):
    """Polls a cheap, explicit condition (a counter, a file) until it holds; bounded."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(step_s)
