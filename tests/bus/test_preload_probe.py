"""The preload library under a multithreaded C program (ucan/tests/preload_probe.c)
that forks while another thread waits for the hub, polls and reads before bind,
and closes descriptors behind the library's back (issue 19, defects 6-8). The
before-bind and closed-descriptor probes hold on kernel vcan as well."""
from __future__ import annotations

import subprocess

import pytest
from conftest import require_userspace
from hubclient import Stopped

pytestmark = pytest.mark.bus
WAIT_S = 30


def start_probe(bus, *args: str) -> subprocess.Popen:
    return bus.popen([bus.tool("preload_probe"), *args], stdin=subprocess.PIPE, bufsize=1)


def expect(proc: subprocess.Popen, wanted: str) -> list[str]:
    """Lines up to the one equal to wanted (ok:/FAIL: results included)."""
    lines = []
    while (line := proc.stdout.readline()) != "":
        lines.append(line.strip())
        if line.strip() == wanted:
            return lines
    raise AssertionError(f"probe ended before '{wanted}': {lines} {proc.stderr.read()}")


def finish(proc: subprocess.Popen, before: list[str]) -> list[str]:
    out, err = proc.communicate(timeout=WAIT_S)
    lines = before + out.splitlines()
    assert proc.returncode == 0 and not [line for line in lines if line.startswith("FAIL")], (lines, err)
    return lines


def test_fork_while_a_thread_waits_for_the_hub(bus):
    """Defect 6: no pthread_atfork, and the interface cache's lock held across a hub query:
    a child forked meanwhile blocked forever in if_nametoindex."""
    require_userspace(bus, "the hub is stopped to make its answer slow")
    probe = start_probe(bus, "fork", "vcan0")
    lines = expect(probe, "ready")
    with Stopped(bus.hub.pid):
        probe.stdin.write("stopped\n")
        lines += expect(probe, "resume")
    finish(probe, lines)


def test_unbound_socket_polls_and_reads_like_the_kernels(bus):
    """Defect 7: poll/epoll on an unbound emulated socket reported POLLHUP at once (kernel:
    times out), recv ignored SO_RCVTIMEO and blocked forever."""
    probe = start_probe(bus, "unbound", "vcan0")
    lines = expect(probe, "ready")
    bus.run(["cansend", "vcan0", "1AB#01"])
    lines = finish(probe, lines)
    assert lines[-1] == "ok: after bind: frame 1AB"


def test_descriptor_closed_behind_the_librarys_back_is_not_can_any_more(bus):
    """Defect 8: a descriptor closed by fclose(fdopen(fd)) or the raw syscall stayed a CAN
    socket in the library's table: the pipe or UDP socket reusing it was treated as CAN."""
    probe = start_probe(bus, "stale", "vcan0")
    finish(probe, [])


def test_socket_inherited_across_exec_after_the_switch_to_stamps_loses_no_frame(bus):
    """Frames queued before SO_TIMESTAMPNS reach the socket bare, the hub's frames with headers
    behind them; a program exec'd with the socket took the hub's mode of now (headers) and
    recvmmsg dropped the bare frames unseen (2 of 4), read() returned them as garbage (id 0)."""
    probe = start_probe(bus, "exec", "vcan0")
    lines = finish(probe, [])
    assert sum(line.startswith("ok: recvmmsg frame") for line in lines) == 4, lines
    assert sum(line.startswith("ok: read frame") for line in lines) == 4, lines


def test_a_reader_that_did_not_see_the_switch_to_stamps_reads_whole_frames(bus):
    """A socket shared by two readers (threads, or here a child forked before): the one that
    asked for stamps switched (reading the hub's notice of it, when the hub still sent one), the
    other read the frames behind it in the bare layout: a 40-byte message cut to the program's 16
    (a header's bytes as the frame)."""
    probe = start_probe(bus, "switch", "vcan0")
    lines = finish(probe, [])
    assert sum(line.startswith("ok: recvmmsg frame") for line in lines) == 3, lines
    assert sum(line.startswith("ok: read frame") for line in lines) == 3, lines
