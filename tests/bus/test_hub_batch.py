"""Several frames in one hub message (UCAN_MSG_FRAMES, what the preload's sendmmsg sends):
the hub transmits them as if each had come alone (order, interfaces, classic and FD, the
counters), and refuses a malformed batch whole: nothing of it reaches the bus."""
from __future__ import annotations

import pytest
from hubclient import IFINDEX_VCAN0, Client, OwnHub, Stopped, can_frame, frame, frames, sockopts

pytestmark = pytest.mark.bus

IFINDEX_VCAN1 = IFINDEX_VCAN0 + 1
CANFD_FDF = 0x04  # the hub marks every FD frame, as linux >= 6.0 does


def fd_reader(hub: OwnHub) -> Client:
    reader = Client(hub.workdir)
    reader.send(sockopts(fd_frames=True))
    assert reader.ack() == 0
    return reader


def test_a_batch_is_its_frames_in_order_on_their_interfaces(tmp_path):
    with OwnHub(tmp_path / "hub", "vcan0", "vcan1:mtu=16") as hub:
        reader0, reader1, sender = fd_reader(hub), Client(hub.workdir), Client(hub.workdir)
        reader1.bind(ifindex=IFINDEX_VCAN1)
        sender.bind()
        fd_data = bytes(range(64))
        sender.send(frames([(IFINDEX_VCAN0, can_frame(0x100, b"\x01")),
                            (IFINDEX_VCAN0, can_frame(0x200, fd_data)),
                            (IFINDEX_VCAN1, can_frame(0x300, b"\x03\x03")),
                            (IFINDEX_VCAN0, can_frame(0x101, b"\x02"))]))
        assert reader0.recv() == can_frame(0x100, b"\x01")
        fd = reader0.recv()
        assert len(fd) == 72 and fd[:4] == (0x200).to_bytes(4, "little") and fd[5] == CANFD_FDF and fd[8:] == fd_data
        assert reader0.recv() == can_frame(0x101, b"\x02")
        assert reader1.recv() == can_frame(0x300, b"\x03\x03")
        stats = hub.stats()
        by_name = {i["name"]: i for i in stats["interfaces"]}
        assert (by_name["vcan0"]["frames"], by_name["vcan1"]["frames"]) == (3, 1), by_name
        sent = next(c for c in stats["clients"] if c["cookie"] == sender.cookie)
        assert sent["tx_frames"] == 4, sent


GOOD = (IFINDEX_VCAN0, can_frame(0x100))
IFINDEX_PACED = IFINDEX_VCAN0 + 2


@pytest.mark.parametrize("message,why", [
    (frames([GOOD, (7, can_frame(0x1FF))]), "unknown interface index"),
    (frames([GOOD, (IFINDEX_VCAN1, can_frame(0x1FF, bytes(64)))]), "FD frame on a classic interface"),
    (frames([GOOD, (IFINDEX_VCAN0, can_frame(0x1FF)[:15])]), "record cut short"),
    (frames([GOOD, (IFINDEX_PACED, can_frame(0x1FF))]), "frame for a bitrate= interface"),
    (frames([GOOD, GOOD]) + b"\0\0\0\0", "bytes after the last record"),
    (frames([GOOD, GOOD], count=3), "a count past the records"),
    (frames([GOOD] * 400), "longer than a message (8192 bytes)"),
])
def test_a_malformed_batch_is_refused_whole(tmp_path, message, why):
    with OwnHub(tmp_path / "hub", "vcan0", "vcan1:mtu=16", "vcan2:bitrate=500000") as hub:
        reader, sender, marker = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
        reader.bind()
        sender.bind()
        marker.bind()
        sender.send(message)
        sender.sock.settimeout(10.0)
        try:
            assert sender.sock.recv(64) == b"", f"{why}: the hub kept the sender"
        except ConnectionResetError:
            pass  # closed with our frames unread: the same refusal
        marker.send(frame(0x7FF))
        assert reader.recv() == can_frame(0x7FF), f"{why}: a frame of the refused batch reached the bus"
        assert hub.stats()["hub"]["proto_errors"] == 1


FIRST_READ = 8  # ucan/src/hub.c: messages in a sender's first read of a wakeup


@pytest.mark.parametrize("seen_before,most_batches_first", [("batch", 2), ("single frames", FIRST_READ)])
def test_a_batch_counts_its_frames_in_the_wakeup_budget(tmp_path, seen_before, most_batches_first):
    """The hub reads 256 frames from one sender per wakeup, then serves the others: a sender
    seen sending batches is read a batch at a time, one last seen sending single frames at
    most FIRST_READ messages in a wakeup's first read. So a frame another client sent behind
    a socketful of 300-frame batches comes after a few of them, not after all. Counting
    messages, the hub handled them all first (64 per read: 7800 of 7800 frames)."""
    with OwnHub(tmp_path / "hub", "vcan0") as hub:
        reader, flood, other = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
        reader.send(sockopts(rcvbuf=64 << 20))  # room for every flood frame: none dropped
        assert reader.ack() == 0
        flood.bind()
        other.bind()
        batch = frames([(IFINDEX_VCAN0, can_frame(0x600))] * 300)
        if seen_before == "batch":
            flood.send(batch)
            warmup = 300
        else:
            for _ in range(warmup := 10):
                flood.send(frame(0x600))
        for _ in range(warmup):
            assert reader.recv() == can_frame(0x600)
        flood.sock.setblocking(False)
        with Stopped(hub.proc.pid):
            sent = 0
            try:
                while sent < 100:
                    flood.send(batch)
                    sent += 1
            except BlockingIOError:
                pass
            other.send(frame(0x010))
        assert sent > most_batches_first + 4, sent
        before = 0
        while reader.recv() != can_frame(0x010):
            before += 1
        assert before <= most_batches_first * 300, (
            f"{before} of {sent * 300} flood frames were delivered before the other's frame")
