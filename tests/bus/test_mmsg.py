"""recvmmsg and sendmmsg on CAN_RAW sockets (ucan/tests/mmsg_probe.c): the kernel's
semantics (MSG_WAITFORONE, MSG_DONTWAIT, the timeout checked after each message and
written back, msg_len, MSG_TRUNC, one SCM_TIMESTAMP(NS) per message, msg_name, sendmmsg
stopping at an invalid frame) on kernel vcan where it exists and on the userspace hub,
and the hub's frames moved several per syscall, as the kernel moves them."""
from __future__ import annotations

import math
import re
import shutil

import pytest
from conftest import require_userspace

pytestmark = pytest.mark.bus
WAIT_S = 30
BURST = 400
HUB_MMSG_CHUNK = 64  # ucan/src/preload.c MMSG_CHUNK: hub messages per real recvmmsg
# classic frames the preload puts in one UCAN_MSG_FRAMES of at most 8192 bytes (UCAN_MSG_MAX; it
# stops when an FD record might not fit): 8 + 338 * (8 + 16) = 8120 bytes
HUB_BATCH_FRAMES, HUB_BATCH_BYTES = 338, 8120
PACED_BURST = 40


def probe_lines(bus, *args: str) -> list[str]:
    rc = bus.run([bus.tool("mmsg_probe"), *args], check=False, timeout=WAIT_S)
    lines = rc.stdout.splitlines()
    assert rc.returncode == 0 and lines and not [line for line in lines if not line.startswith("ok:")], (
        lines, rc.stderr)
    return lines


def test_recvmmsg_and_sendmmsg_as_the_kernel_defines_them(bus):
    """Before the preload batched them, recvmmsg ignored its timeout (never EINVAL, nothing
    written back, a zero timeout returned all that was queued) and without MSG_WAITFORONE
    returned what was queued instead of waiting for vlen messages; a frame cut to 8 bytes by
    the buffer was taken for a control reply and dropped (recv() then blocked)."""
    lines = probe_lines(bus, "checks", "vcan0")
    assert len(lines) == 17, lines


def syscalls_in_burst(trace: str) -> dict[str, int]:
    """Syscall names and counts between the probe's burst-start and burst-end markers."""
    counts: dict[str, int] = {}
    inside = False
    for line in trace.splitlines():
        if '"burst-start"' in line:
            inside = True
        elif '"burst-end"' in line:
            break
        elif inside and (m := re.match(r"(?:\d+\s+)?(\w+)\(", line)):
            counts[m.group(1)] = counts.get(m.group(1), 0) + 1
    assert inside, trace[-2000:]
    return counts


def burst_syscalls(bus, tmp_path, frames: int) -> tuple[int, int, str]:
    """Syscalls (sends, receives) of the probe's burst of frames out with one sendmmsg and
    back with one blocking recvmmsg, and the trace."""
    trace = tmp_path / "strace.txt"
    bus.run(["strace", "-f", "-o", str(trace), "-e", "trace=%network,read,write,readv,writev",
             bus.tool("mmsg_probe"), "burst", "vcan0", str(frames)], timeout=WAIT_S)
    counts = syscalls_in_burst(trace.read_text())
    sends = sum(counts.get(name, 0) for name in ("sendmmsg", "sendmsg", "sendto", "write", "writev"))
    receives = sum(counts.get(name, 0) for name in ("recvmmsg", "recvmsg", "recvfrom", "read", "readv"))
    return sends, receives, trace.read_text()


needs_strace = pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace to count syscalls")


@needs_strace
def test_a_burst_takes_a_syscall_per_chunk_not_per_frame(bus, tmp_path):
    """400 frames out with one sendmmsg and back with one blocking recvmmsg: the kernel takes
    one syscall each; over the hub one send per 338 frames (each a single hub message, so
    the kernel moves one message, not one per frame) and one recvmmsg per 64. Before, the
    preload looped (400 sendto and 400 recvmsg), then sent one message per frame."""
    sends, receives, trace = burst_syscalls(bus, tmp_path, BURST)
    assert sends <= math.ceil(BURST / HUB_BATCH_FRAMES) and receives <= math.ceil(BURST / HUB_MMSG_CHUNK), (
        sends, receives)
    if bus.mode == "userspace":  # one message of 338 frames went, not a sendmmsg of 338 messages
        assert f", {HUB_BATCH_BYTES}, " in trace and f"= {HUB_BATCH_BYTES}" in trace, trace[-2000:]


@needs_strace
def test_a_burst_on_a_paced_interface_goes_frame_by_frame(bus, tmp_path):
    """On a bitrate= interface every frame waits for the wire, and one hub message per frame
    keeps the backpressure a sender feels (messages in flight to the hub) what it was."""
    require_userspace(bus, "bitrate emulation")
    bus.stop_hub()
    bus.start_hub("vcan0:bitrate=1000000")
    sends, _, _ = burst_syscalls(bus, tmp_path, PACED_BURST)
    assert sends == PACED_BURST, sends
