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


@pytest.mark.parametrize("bad_record,why", [
    ((7, can_frame(0x1FF)), "unknown interface index"),
    ((IFINDEX_VCAN1, can_frame(0x1FF, bytes(64))), "FD frame on a classic interface"),
    ((IFINDEX_VCAN0, can_frame(0x1FF)[:15]), "record cut short"),
])
def test_a_malformed_batch_is_refused_whole(tmp_path, bad_record, why):
    with OwnHub(tmp_path / "hub", "vcan0", "vcan1:mtu=16") as hub:
        reader, sender, marker = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
        reader.bind()
        sender.bind()
        marker.bind()
        sender.send(frames([(IFINDEX_VCAN0, can_frame(0x100)), bad_record]))
        sender.sock.settimeout(10.0)
        try:
            assert sender.sock.recv(64) == b"", f"{why}: the hub kept the sender"
        except ConnectionResetError:
            pass  # closed with our frames unread: the same refusal
        marker.send(frame(0x7FF))
        assert reader.recv() == can_frame(0x7FF), f"{why}: a frame of the refused batch reached the bus"
        assert hub.stats()["hub"]["proto_errors"] == 1


def test_a_batch_counts_its_frames_in_the_wakeup_budget(tmp_path):
    """The hub reads 256 frames from one sender per wakeup, then serves the others: a sender
    of batches is read one batch at a time once it has been seen sending them, so a frame
    another client sent behind a socketful of 300-frame batches comes after one or two of
    them, not after all. Counting messages, the hub handled them all first (64 per read)."""
    with OwnHub(tmp_path / "hub", "vcan0") as hub:
        reader, flood, other = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
        reader.send(sockopts(rcvbuf=64 << 20))  # room for every flood frame: none dropped
        assert reader.ack() == 0
        flood.bind()
        other.bind()
        batch = frames([(IFINDEX_VCAN0, can_frame(0x600))] * 300)
        flood.send(batch)
        for _ in range(300):
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
        assert sent >= 8, sent
        before = 0
        while reader.recv() != can_frame(0x010):
            before += 1
        assert before <= 2 * 300, f"{before} of {sent * 300} flood frames were delivered before the other's frame"


def test_hub_refuses_a_batch_larger_than_a_message(tmp_path):
    with OwnHub(tmp_path / "hub", "vcan0") as hub:
        sender = Client(hub.workdir)
        sender.bind()
        sender.send(frames([(IFINDEX_VCAN0, can_frame(0x600))] * 400))  # 9608 bytes > 8192
        sender.sock.settimeout(10.0)
        try:
            assert sender.sock.recv(64) == b""
        except (TimeoutError, ConnectionResetError) as e:
            assert isinstance(e, ConnectionResetError), "the hub kept a sender of an oversized message"
        assert hub.stats()["hub"]["proto_errors"] == 1
