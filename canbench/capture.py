"""Capture both sides of the bridge during a run, to files analysed later:
the CAN bus with candump -L (C, kernel/hub timestamps) and every Zenoh
sample under the bridge's key prefix with its receive time and attachment."""
from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import zenoh

from .runkeys import wait_until


def kernel_can_receivers() -> int:
    """Receive-list entries of the kernel's CAN core: one per filter of every bound CAN_RAW
    socket, in whichever list the filter landed (rcvlist_all has only the match-all ones)."""
    count = 0
    for path in Path("/proc/net/can").glob("rcvlist_*"):
        for line in path.read_text().splitlines():
            fields = line.split()
            # entries: "  vcan0  123  000007FF  <function>  <userdata>  <matches>  <ident>"
            if len(fields) >= 6 and (fields[0].startswith("vcan") or fields[0] == "any"):
                count += 1
    return count


def bound_can_receivers() -> int:
    """Bound CAN_RAW sockets on the bus: the hub's count, or the kernel's receive lists."""
    ucan_dir = os.environ.get("UCAN_DIR", "/run/ucan")
    if os.environ.get("LD_PRELOAD") and os.path.exists(f"{ucan_dir}/hub.sock"):
        out = subprocess.run(["ucanctl", "-d", ucan_dir, "stats", "-j"], capture_output=True, text=True,
                             env={k: v for k, v in os.environ.items() if k != "LD_PRELOAD"})
        return sum(1 for c in json.loads(out.stdout)["clients"] if c["bound"]) if out.returncode == 0 else 0
    return kernel_can_receivers()


class CanCapture:
    """candump -L of the given interfaces into a file."""

    def __init__(self, path: Path, interfaces: list[str]):
        self.path = path
        before = bound_can_receivers()
        self.out = open(path, "w")
        self.proc = subprocess.Popen(["candump", "-L", *interfaces], stdout=self.out, stderr=subprocess.PIPE)
        wait_until(lambda: bound_can_receivers() >= before + len(interfaces) or self.proc.poll() is not None,
                   10, "candump bound to the bus")
        if self.proc.poll() is not None:
            raise RuntimeError(f"candump exited: {self.proc.stderr.read().decode() if self.proc.stderr else ''}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            self.proc.wait(timeout=10)
        self.out.close()


class ZenohCapture:
    """Every sample under key_expr, with local receive time (ns since the epoch)."""

    def __init__(self, session: zenoh.Session, key_expr: str):
        self.samples: list[tuple[int, str, bytes, bytes | None]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        with self.lock:
            self.samples.append((now, str(sample.key_expr), sample.payload.to_bytes(), att))

    def frames_on(self, keys: set[str]) -> int:
        """16-byte frames received so far on these keys."""
        with self.lock:
            return sum(len(payload) // 16 for _, key, payload, _ in self.samples if key in keys)

    def frames_with_ids(self, ids_by_key: dict[str, set[int]]) -> int:
        """Frames received so far on these keys whose id is in that key's set."""
        with self.lock:
            samples = [(key, payload) for _, key, payload, _ in self.samples if key in ids_by_key]
        count = 0
        for key, payload in samples:
            for i in range(0, len(payload) - len(payload) % 16, 16):
                count += int.from_bytes(payload[i:i + 4], "little") in ids_by_key[key]
        return count

    def stop(self, path: Path) -> None:
        self.sub.undeclare()
        with open(path, "w") as f, self.lock:
            f.writelines(json.dumps({"t_ns": t, "key": key, "payload": base64.b64encode(payload).decode(),
                                    "attachment": base64.b64encode(att).decode() if att is not None else None})
                        + "\n" for t, key, payload, att in self.samples)


def read_zenoh_capture(path: Path) -> list[tuple[int, str, bytes, bytes | None]]:
    out = []
    for line in open(path):
        d = json.loads(line)
        out.append((d["t_ns"], d["key"], base64.b64decode(d["payload"]),
                    base64.b64decode(d["attachment"]) if d["attachment"] is not None else None))
    return out
