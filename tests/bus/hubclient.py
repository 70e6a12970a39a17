"""Raw clients of the userspace hub for the abuse tests (test_hub_abuse.py): the
messages of ucan/include/ucan_proto.h built by hand, as a hostile or broken
program would send them, plus the hub process's state (stopped, RSS, CPU)."""
from __future__ import annotations

import os
import signal
import socket
import struct
from pathlib import Path

from conftest import wait_for

IFINDEX_VCAN0 = 10000
MSG_ACK, MSG_HEADER_MODE = 1, 2
(MSG_BIND, MSG_SETOPT, MSG_FRAME, MSG_IFLIST, MSG_BARRIER, MSG_STATS, MSG_RESET_STATS, MSG_GETOPT,
 MSG_FRAMES) = range(10, 19)
COOKIE_MAX = 64
CTL = struct.Struct("=Ii")          # ucan_ctl
SOCKOPTS = struct.Struct("=IIIIBBBBBBBBI")  # ucan_sockopts without its filters
RXHDR_SIZE = 24                     # ucan_rxhdr: what a headed frame (40 / 96 bytes) starts with


def sockopts(ifindex: int = IFINDEX_VCAN0, rcvbuf: int = 0, recv_own: bool = False, loopback: bool = True,
             timestamps: int = 0, kind: int = MSG_BIND, fd_frames: bool = False) -> bytes:
    """BIND/SETOPT with the kernel's default filter {0, 0} (everything)."""
    return SOCKOPTS.pack(kind, ifindex, 0, rcvbuf, int(loopback), int(recv_own), int(fd_frames), 0, 0, 0,
                         timestamps, 0, 1) + struct.pack("=II", 0, 0)


def can_frame(can_id: int, data: bytes = b"") -> bytes:
    """struct can_frame (16 bytes), or struct canfd_frame (72) for more than 8 data bytes."""
    if len(data) > 8:
        return struct.pack("=IBBxx64s", can_id, len(data), 0, data)
    return struct.pack("=IB3x8s", can_id, len(data), data)


def frame(can_id: int, data: bytes = b"", ifindex: int = IFINDEX_VCAN0) -> bytes:
    return struct.pack("=II", MSG_FRAME, ifindex) + can_frame(can_id, data)


def frames(records: list[tuple[int, bytes]], count: int | None = None) -> bytes:
    """UCAN_MSG_FRAMES: (ifindex, struct can_frame or canfd_frame bytes) records."""
    body = b"".join(struct.pack("=II", ifindex, len(raw)) + raw for ifindex, raw in records)
    return struct.pack("=II", MSG_FRAMES, len(records) if count is None else count) + body


def barrier(cookie: str, kind: int = MSG_BARRIER) -> bytes:
    return struct.pack("=I", kind) + cookie.encode().ljust(COOKIE_MAX, b"\0")


def query(kind: int) -> bytes:
    return struct.pack("=I", kind)


class Client:
    """One connection to the hub, named (abstract address) like the preload library's sockets."""

    count = 0

    def __init__(self, workdir: Path, name: str | None = None):
        Client.count += 1
        self.cookie = name or f"ucan/test/{os.getpid()}/{Client.count}"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.sock.bind("\0" + self.cookie)
        self.sock.connect(str(workdir / "hub.sock"))

    def send(self, msg: bytes) -> None:
        self.sock.send(msg)

    def recv(self, timeout: float = 10.0) -> bytes:
        self.sock.settimeout(timeout)
        return self.sock.recv(8192)

    def ack(self, timeout: float = 10.0) -> int:
        """The status of the next control reply (0 = ok)."""
        msg = self.recv(timeout)
        assert len(msg) == CTL.size, f"expected a control reply, got {len(msg)} bytes: {msg.hex()}"
        kind, status = CTL.unpack(msg)
        assert kind == MSG_ACK, kind
        return status

    def bind(self, **opts) -> None:
        self.send(sockopts(**opts))
        assert self.ack() == 0

    def close(self) -> None:
        self.sock.close()


def proc_status(pid: int, field: str) -> str:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return line.split(":", 1)[1].strip()
    raise KeyError(field)


def rss_kib(pid: int) -> int:
    return int(proc_status(pid, "VmRSS").split()[0])


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


class Stopped:
    """The hub stopped (SIGSTOP) for the block: what clients send meanwhile is handled in one
    loop round when it continues, in the order it became readable."""

    def __init__(self, pid: int):
        self.pid = pid

    def __enter__(self):
        os.kill(self.pid, signal.SIGSTOP)
        wait_for(lambda: proc_status(self.pid, "State").startswith("T"), "the hub stopped")
        return self

    def __exit__(self, *exc):
        os.kill(self.pid, signal.SIGCONT)



class OwnHub:
    """A hub of the test's own in a directory of its own, started with a descriptor limit
    (the bus fixture's hub stays as it is). A context manager: stopped on exit."""

    def __init__(self, directory: Path, *args: str, nofile: int | None = None):
        import resource
        import subprocess

        from conftest import BUILD

        def limit() -> None:
            if nofile is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

        directory.mkdir()
        self.workdir, self.log, self.build = directory, directory / "hub.log", BUILD
        read_fd, write_fd = os.pipe()
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([str(BUILD / "ucan-hub"), "-d", str(directory), "-r", str(write_fd), *args],
                                         stdout=log, stderr=log, pass_fds=(write_fd,), preexec_fn=limit,
                                         env={k: v for k, v in os.environ.items() if k != "LD_PRELOAD"})
        os.close(write_fd)
        with os.fdopen(read_fd) as ready:
            assert ready.readline().strip() == "ready", self.log.read_text()

    def stats(self) -> dict:
        import json
        import subprocess
        out = subprocess.run([str(self.build / "ucanctl"), "-d", str(self.workdir), "stats", "-j"],
                             capture_output=True, text=True, check=True)
        return json.loads(out.stdout)

    def __enter__(self) -> OwnHub:
        return self

    def __exit__(self, *exc) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
