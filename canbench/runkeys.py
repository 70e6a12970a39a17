"""Zenoh keys the bench uses to coordinate a run between containers (never
sleeps: each side waits for an explicit signal), and the client session
every bench process opens: explicit endpoint, multicast scouting off."""
from __future__ import annotations

import json
import threading
import time

import zenoh


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


def open_session(endpoint: str, wait: bool = True) -> zenoh.Session:
    """wait: for the router rather than fail, and back within a second of a router restart;
    without, zenoh's defaults (the tests: a router they started is already listening)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if wait:
        conf.insert_json5("connect/timeout_ms", "-1")
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
