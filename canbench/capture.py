"""Capture both sides of the bridge during a run, to files analysed later,
both in compiled code so the capture keeps up at 100k+ frames/s: the CAN bus
with candump -L (kernel/hub timestamps) into can.log, and every Zenoh sample
under the bridge's key prefix with its receive time and attachment, by
zn-capture (firmware/ports/linux/zenoh_rust/src/bin) into zenoh.tsv."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
from collections import Counter
from pathlib import Path

import zenoh

from .runkeys import wait_token, wait_until


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


# candump -r: a deep receive queue, so the bench's own capture rides out a flood or a
# moment without CPU (the hub sizes a reader's queue from SO_RCVBUF; the kernel caps it at
# rmem_max unless the capture has CAP_NET_ADMIN). 64 MiB is ~900k frames on the hub.
CAPTURE_RCVBUF = 64 << 20


class CanCapture:
    """candump -L of the given interfaces into a file."""

    def __init__(self, path: Path, interfaces: list[str]):
        self.path = path
        before = bound_can_receivers()
        self.out = open(path, "w")
        self.proc = subprocess.Popen(["candump", "-L", "-r", str(CAPTURE_RCVBUF), *interfaces], stdout=self.out,
                                     stderr=subprocess.PIPE)
        wait_until(lambda: bound_can_receivers() >= before + len(interfaces) or self.proc.poll() is not None,
                   10, "candump bound to the bus")
        if self.proc.poll() is not None:
            raise RuntimeError(f"candump exited: {self.proc.stderr.read().decode() if self.proc.stderr else ''}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            self.proc.wait(timeout=10)
        self.out.close()


def zn_capture_binary() -> str:
    """zn-capture: $ZN_CAPTURE, else on PATH (the images), else the host build (make firmware)."""
    candidates = [os.environ.get("ZN_CAPTURE"), shutil.which("zn-capture"),
                  str(Path(__file__).resolve().parents[1] / "build" / "firmware" / "zn-capture")]
    for c in candidates:
        if c and os.access(c, os.X_OK):
            return c
    raise RuntimeError("zn-capture not found: set ZN_CAPTURE, put it on PATH, or build it (make firmware)")


class ZenohCapture:
    """Every sample under key_expr with its receive time and attachment, recorded by
    zn-capture (Rust, one callback per sample) into a file; counts read from that file
    as it grows. Ready when its liveliness token (declared after the subscriber, on the
    capture's own session) is visible through `session`."""

    def __init__(self, session: zenoh.Session, endpoint: str, key_expr: str, path: Path, token: str,
                 timeout_s: float = 30):
        self.path = path
        self.proc = subprocess.Popen([zn_capture_binary(), "--connect", endpoint, "--key", key_expr,
                                      "--ready-token", token, "--out", str(path)],
                                     stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        self._offset = 0
        self._partial = b""
        self._frames: Counter = Counter()          # key -> 16-byte frames
        self._ids: dict[str, Counter] = {}         # key -> id -> frames
        try:
            wait_token(session, token, timeout_s)
        except TimeoutError:
            self.proc.kill()
            err = self.proc.communicate()[1].decode(errors="replace")
            raise RuntimeError(f"zn-capture did not become ready within {timeout_s:.0f} s: {err.strip()}") from None

    def _poll(self) -> None:
        with open(self.path, "rb") as f:
            f.seek(self._offset)
            chunk = f.read()
        self._offset += len(chunk)
        data = self._partial + chunk
        lines = data.split(b"\n")
        self._partial = lines.pop()
        for line in lines:
            _, key_b, payload_hex, _ = line.split(b"\t")
            key = key_b.decode()
            n = len(payload_hex) // 32
            self._frames[key] += n
            ids = self._ids.setdefault(key, Counter())
            for i in range(n):
                ids[int.from_bytes(bytes.fromhex(payload_hex[32 * i:32 * i + 8].decode()), "little")] += 1

    def frames_on(self, keys: set[str]) -> int:
        """16-byte frames received so far on these keys."""
        self._poll()
        return sum(self._frames[k] for k in keys)

    def frames_with_ids(self, ids_by_key: dict[str, set[int]]) -> int:
        """Frames received so far on these keys whose id is in that key's set."""
        self._poll()
        return sum(self._ids.get(k, Counter())[i] for k, ids in ids_by_key.items() for i in ids)

    def stop(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # zn-capture stops at end of its stdin
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                raise RuntimeError("zn-capture did not stop within 10 s") from None
        if self.proc.returncode != 0:
            err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
            raise RuntimeError(f"zn-capture failed (exit {self.proc.returncode}): {err.strip()}")


def read_zenoh_capture(path: Path) -> list[tuple[int, str, bytes, bytes | None]]:
    """zn-capture's file: (receive time ns, key, payload, attachment or None) per sample."""
    out = []
    for line in open(path):
        t_ns, key, payload, att = line.rstrip("\n").split("\t")
        out.append((int(t_ns), key, bytes.fromhex(payload), None if att == "-" else bytes.fromhex(att)))
    return out
