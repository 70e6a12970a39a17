"""The userspace hub against hostile and broken clients (issue 19, defects 1-5):
raw connections (hubclient.py) doing what no well-behaved program does, the hub
paused (SIGSTOP) so that a whole sequence lands in one loop round. Every test
checks the hub still serves, and its memory stays under a stated ceiling."""
from __future__ import annotations

import stat
import time

import pytest
from conftest import require_userspace
from hubclient import (
    MSG_RESET_STATS,
    MSG_SETOPT,
    RXHDR_SIZE,
    Client,
    OwnHub,
    Stopped,
    barrier,
    cpu_seconds,
    frame,
    query,
    rss_kib,
    sockopts,
)

pytestmark = pytest.mark.bus

# The hub's RSS may grow by at most this much under any abuse below (its queues for the
# well-behaved clients of a test are a few hundred KiB; the ASan hub's shadow adds some).
RSS_GROWTH_CEILING_KIB = 16 * 1024


@pytest.fixture
def hub(bus):
    require_userspace(bus, "raw clients of the hub's protocol")
    bus.rss_before = rss_kib(bus.hub.pid)
    yield bus
    assert bus.hub.poll() is None, bus.hub_log.read_text()[-3000:]
    grown = rss_kib(bus.hub.pid) - bus.rss_before
    assert grown < RSS_GROWTH_CEILING_KIB, f"hub RSS grew by {grown} KiB"


def still_serves(bus) -> None:
    reader, sender = Client(bus.workdir), Client(bus.workdir)
    reader.bind()
    sender.send(frame(0x7AB, b"\x01"))
    assert reader.recv() == frame(0x7AB, b"\x01")[8:]


def test_slot_reused_in_the_round_it_was_freed_is_flushed_once(hub):
    """Defect 1: 64 clients (every slot) all have a frame queued, one closes, a new client takes
    its slot and is named by a BARRIER in the same round: its reply must not be listed twice
    (the ASan hub found a heap-buffer-overflow in client_send)."""
    clients = [Client(hub.workdir) for _ in range(64)]
    sender, closing, barrier_sender = clients[0], clients[1], clients[2]
    sender.bind(recv_own=True)  # its own echo makes every slot dirty, its own too
    for c in clients[1:]:
        c.bind()
    with Stopped(hub.hub.pid):
        sender.send(frame(0x123, b"\x11"))
        closing.close()
        newcomer = Client(hub.workdir)  # accepted into the closed client's slot
        newcomer.send(sockopts())
        barrier_sender.send(barrier(newcomer.cookie))
    assert barrier_sender.recv() == frame(0x123, b"\x11")[8:]
    assert barrier_sender.ack() == 0
    assert newcomer.ack() == 0
    for c in clients[3:]:
        assert c.recv() == frame(0x123, b"\x11")[8:]
    still_serves(hub)


def test_client_that_never_reads_its_replies_is_closed_not_queued_for(hub):
    """Defect 2: control replies were queued past every limit: 1M RESET_STATS from a client that
    never reads grew the hub from 1.5 MB to 81 MB. Now UCAN_CTL_RESERVE replies past a full queue
    close it, counted."""
    greedy = Client(hub.workdir)
    sent = 0
    with pytest.raises(OSError):  # the hub hangs up on it
        while sent < 400_000:
            greedy.send(query(MSG_RESET_STATS))
            sent += 1
    assert sent < 100_000, sent
    assert hub.stats()["hub"]["unread_closes"] == 1
    still_serves(hub)


def test_receive_buffer_asked_is_clamped(hub):
    """Defect 2: SO_RCVBUF set the reader's queue limit unclamped (4 GiB asked: ~59 M frames)."""
    huge, plain = Client(hub.workdir), Client(hub.workdir)
    huge.bind(rcvbuf=0xFFFFFFFF)
    plain.bind(rcvbuf=64 * 72 * 1000)  # 64 k frames: honoured
    limits = {c["cookie"]: c["queue_limit"] for c in hub.stats()["clients"]}
    assert limits[huge.cookie] == (64 << 20) // 72  # UCAN_MAX_RCVBUF
    assert limits[plain.cookie] == 64_000



def test_out_of_descriptors_refuses_connections_without_spinning(hub):
    """Defect 3: with level-triggered epoll a failed accept (EMFILE) left the listening socket
    readable forever: 1.7 s of CPU per 2 s idle and a 27 MB log under --nofile=32. Now the
    connection is accepted on a spare descriptor and closed at once, counted."""
    with OwnHub(hub.workdir / "nofile", "vcan0", nofile=32) as small:
        rss_before = rss_kib(small.proc.pid)
        clients = [Client(small.workdir) for _ in range(40)]  # more than 32 descriptors can hold
        start_cpu, start = cpu_seconds(small.proc.pid), time.monotonic()
        while time.monotonic() - start < 1.0:  # a measurement window, not a wait for something
            time.sleep(0.1)
        busy = cpu_seconds(small.proc.pid) - start_cpu
        assert busy < 0.2, f"hub used {busy:.2f} s of CPU in 1 s with connections it cannot accept"
        assert clients[-1].recv() == b""  # refused: the hub hung up
        assert small.log.stat().st_size < 10_000
        for c in clients:
            c.close()
        assert small.stats()["hub"]["refused_connections"] >= 8
        assert small.proc.poll() is None
        assert rss_kib(small.proc.pid) - rss_before < RSS_GROWTH_CEILING_KIB
        still_serves(small)


def test_barrier_drains_its_target_without_losing_the_rest_of_its_batch(hub):
    """Defect 4: a BARRIER drained its target into the static buffers the outer loop was still
    reading: the frame sent after the BARRIER in the same batch was lost, another duplicated."""
    reader, querier, target = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
    reader.bind()
    with Stopped(hub.hub.pid):
        querier.send(barrier(target.cookie))  # readable first: handled first when the hub continues
        querier.send(frame(0x100, b"\xf1"))
        target.send(frame(0x200, b"\x01"))
        target.send(frame(0x201, b"\x02"))
    got = [reader.recv() for _ in range(3)]
    assert got == [frame(i, d)[8:] for i, d in ((0x200, b"\x01"), (0x201, b"\x02"), (0x100, b"\xf1"))]
    assert querier.ack() == 0
    by_cookie = {c["cookie"]: c["tx_frames"] for c in hub.stats()["clients"]}
    assert (by_cookie[querier.cookie], by_cookie[target.cookie]) == (1, 2)


def test_barrier_on_a_data_connection_is_answered_not_nested(hub):
    """A BARRIER inside a drained client's input (no well-behaved program sends one there)
    is answered without draining again, and counted."""
    reader, querier, target, third = (Client(hub.workdir) for _ in range(4))
    reader.bind()
    with Stopped(hub.hub.pid):
        querier.send(barrier(target.cookie))
        target.send(barrier(third.cookie))
        target.send(barrier(querier.cookie))
        third.send(frame(0x300, b"\x03"))
    assert querier.ack() == 0 and target.ack() == 0 and target.ack() == 0
    assert reader.recv() == frame(0x300, b"\x03")[8:]
    assert hub.stats()["hub"]["barriers_refused"] == 2


def test_socket_is_for_the_hubs_owner_and_group_only(hub):
    """Defect 5: the socket was world-writable (umask 0): any local user could send frames."""
    assert stat.S_IMODE((hub.workdir / "hub.sock").stat().st_mode) == 0o660
    assert stat.S_IMODE((hub.workdir / "hub.lock").stat().st_mode) & 0o007 == 0


def test_switch_to_headers_sends_no_control_message_on_the_data_socket(hub):
    """After BIND's ACK a data socket carries frames only. A control message queued there
    (the hub's notice of its switch to headers, once) was the one message a MSG_PEEK had to
    consume by a second read: a thread reading the socket meanwhile took the notice, and the
    peeking thread's consume took a frame instead (lost)."""
    reader, sender = Client(hub.workdir), Client(hub.workdir)
    reader.bind()
    reader.send(sockopts(kind=MSG_SETOPT, timestamps=3))  # SO_TIMESTAMPNS: frames carry headers
    sender.send(frame(0x123, b"\x01"))
    first = reader.recv()
    assert len(first) == RXHDR_SIZE + 16, f"expected the frame behind its header, got {len(first)} bytes"
    assert first[RXHDR_SIZE:] == frame(0x123, b"\x01")[8:]
