"""Capture both sides of the bridge during a run, to files analysed later,
both in compiled code so the capture keeps up at 100k+ frames/s: the CAN bus
with candump -L (kernel/hub timestamps) into can.log, and every Zenoh sample
under the bridge's key prefix with its receive time and attachment, by
zn-capture (firmware/ports/linux/zenoh_rust/src/bin) into zenoh.tsv."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import zenoh

from . import wire
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


def _hub_clients() -> list[dict] | None:
    """The userspace hub's clients (ucanctl stats), None on kernel CAN or if the hub does not answer."""
    ucan_dir = os.environ.get("UCAN_DIR", "/run/ucan")
    if not (os.environ.get("LD_PRELOAD") and os.path.exists(f"{ucan_dir}/hub.sock")):
        return None
    out = subprocess.run(["ucanctl", "-d", ucan_dir, "stats", "-j"], capture_output=True, text=True,
                         env={k: v for k, v in os.environ.items() if k != "LD_PRELOAD"})
    return json.loads(out.stdout)["clients"] if out.returncode == 0 else None


def bound_can_receivers() -> int:
    """Bound CAN_RAW sockets on the bus: the hub's count, or the kernel's receive lists."""
    clients = _hub_clients()
    if clients is None:
        return kernel_can_receivers()
    return sum(1 for c in clients if c["bound"])


# candump -r: a deep receive queue, so the bench's own capture rides out a flood or a
# moment without CPU (the hub sizes a reader's queue from SO_RCVBUF; the kernel caps it at
# rmem_max unless the capture has CAP_NET_ADMIN). 64 MiB is ~900k frames on the hub.
CAPTURE_RCVBUF = 64 << 20


class CanCapture:
    """candump -L of the given interfaces into a file. Its drops are counted twice over: candump -d
    writes the kernel's per-socket drop counter (SO_RXQ_OVFL) into the file as DROPCOUNT lines;
    on the userspace bus the hub counts what it dropped for candump's sockets (read at stop)."""

    def __init__(self, path: Path, interfaces: list[str]):
        self.path = path
        before = bound_can_receivers()
        self.out = open(path, "w")
        self.proc = subprocess.Popen(["candump", "-L", "-d", "-r", str(CAPTURE_RCVBUF), *interfaces], stdout=self.out,
                                     stderr=subprocess.PIPE)
        wait_until(lambda: bound_can_receivers() >= before + len(interfaces) or self.proc.poll() is not None,
                   10, "candump bound to the bus")
        if self.proc.poll() is not None:
            raise RuntimeError(f"candump exited: {self.proc.stderr.read().decode() if self.proc.stderr else ''}")

    def stop(self) -> None:
        clients = _hub_clients() if self.proc.poll() is None else None
        if clients is not None:
            pid = self.proc.pid
            mine = [c for c in clients if c.get("pid") == pid or c.get("cookie", "").startswith(f"ucan/{pid}/")]
            # another reader's drops (the bridge's, a device's) explain a loss the oracle finds: kept to be named
            others = [{k: c.get(k) for k in ("cookie", "pid", "iface", "queue_limit", "rx_frames", "rx_drops")}
                      for c in clients if c not in mine and c.get("rx_drops")]
            write_capture_stats(self.path.parent, "can", {"hub_rx_drops": sum(c["rx_drops"] for c in mine),
                                                       "hub_sockets": len(mine), "hub_other_drops": others})
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
        # BENCH_CAPTURE_ZENOH_CONFIG: the capture's own identity (docs/access-control.md)
        identity = os.environ.get("BENCH_CAPTURE_ZENOH_CONFIG")
        self.proc = subprocess.Popen([zn_capture_binary(), "--connect", endpoint, "--key", key_expr,
                                      "--ready-token", token, "--out", str(path),
                                      *(["--zenoh-config", identity] if identity else [])],
                                     stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        self._offset = 0
        self._partial = b""
        self._samples = 0                          # lines read so far
        self._decoded: dict[bytes, wire.Frame] = {}  # frames by their 16 bytes: traffic repeats itself
        self.reported: int | None = None           # zn-capture's own sample count, at stop
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
        if len(self._decoded) > 1 << 16:
            self._decoded.clear()  # only time is at stake
        for line in lines:
            sample = parse_sample_line(line.decode())
            self._samples += 1
            self._frames[sample.key] += len(sample.payload) // wire.WIRE_SIZE
            ids = self._ids.setdefault(sample.key, Counter())
            try:
                ids.update(f.can_id for f in wire.decode_batch(sample.payload, self._decoded))
            except wire.WireError:
                pass  # not a bridge frame: the oracle reports it; nothing to wait for here

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
        err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
        if self.proc.returncode != 0:
            raise RuntimeError(f"zn-capture failed (exit {self.proc.returncode}): {err.strip()}")
        counted = re.search(r"zn-capture: (\d+) samples on", err)
        self.reported = int(counted[1]) if counted else None
        self._poll()
        write_capture_stats(self.path.parent, "zenoh", {"samples_reported": self.reported,
                                                         "samples_written": self._samples})


class Sample(NamedTuple):
    t_ns: int                # receive time, ns since the epoch
    key: str
    payload: bytes
    attachment: bytes | None


def parse_sample_line(line: str) -> Sample:
    """One line of zn-capture's file (grammar in zn-capture.rs), e.g.
    '1700000000000400000<TAB>vehicle/can/rx<TAB>2301000002000000dead000000000000<TAB>-'."""
    fields = line.rstrip("\n").split("\t")
    if len(fields) != 4:
        raise ValueError(f"not a zn-capture line ({len(fields)} fields, not 4): {line[:80]!r}")
    t_ns, key, payload, att = fields
    return Sample(int(t_ns), key, bytes.fromhex(payload), None if att == "-" else bytes.fromhex(att))


def format_sample_line(sample: Sample) -> str:
    """The line zn-capture writes for a sample (tests and benchmarks write captures with it)."""
    att = "-" if sample.attachment is None else sample.attachment.hex()
    return f"{sample.t_ns}\t{sample.key}\t{sample.payload.hex()}\t{att}\n"


def iter_zenoh_capture(path: Path, growing: bool = False) -> Iterator[Sample]:
    """Every sample of a zn-capture file. growing: the capture may still be writing, so a last
    line without its newline is not there yet (skipped, not an error)."""
    with open(path) as f:
        for lineno, line in enumerate(f, 1):
            if growing and not line.endswith("\n"):
                return
            try:
                yield parse_sample_line(line)
            except ValueError as e:
                raise ValueError(f"{path}:{lineno}: {e}") from None


def read_zenoh_capture(path: Path) -> list[Sample]:
    """zn-capture's file: every sample in arrival order."""
    return list(iter_zenoh_capture(path))


CAPTURE_STATS = "captures.json"


def write_capture_stats(run_dir: Path, side: str, stats: dict) -> None:
    """A capture's own counters at stop, by side ("can", "zenoh"), in captures.json: what the
    analysis needs to tell a capture that could not keep up from a bridge that lost frames."""
    path = run_dir / CAPTURE_STATS
    merged = json.loads(path.read_text()) if path.exists() else {}
    merged[side] = stats
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(merged, indent=2))
    tmp.replace(path)


def read_capture_stats(run_dir: Path) -> dict:
    path = run_dir / CAPTURE_STATS
    return json.loads(path.read_text()) if path.exists() else {}
