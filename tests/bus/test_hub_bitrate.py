"""A bitrate= interface pauses senders while 256 frames wait for the wire; a paused
sender that exits still has frames in its socket the hub has not read. Every frame
a write() accepted must reach the bus: before this test the hub closed such a
sender as soon as a write *to* it failed (frames of the other sender it never read,
queued in the hub), and what it had written was lost without a count (bench-qos:
5-13 of 1500 high-id frames and 90-184 of 36 000 flood frames per run)."""
from __future__ import annotations

import socket
import struct
import threading

import pytest
from conftest import wait_for
from hubclient import Client, OwnHub, frame

pytestmark = pytest.mark.bus

HIGH_ID, FLOOD_ID = 0x010, 0x600
HIGH_FRAMES = 2000        # about 0.3 s of wire at 1 Mbit/s: keeps the pending queue full
FLOOD_FRAMES_MAX = 5000   # the flood writes until its socket is full (a few hundred)
CAN_FRAME = struct.Struct("=IB3x8s")


def send_all(sock: socket.socket, msgs: list[bytes]) -> None:
    sock.settimeout(10.0)  # a paused sender waits for the wire: seconds at most
    for m in msgs:
        sock.send(m)


def send_until_full(sock: socket.socket, ident: int, limit: int) -> int:
    """Writes without waiting until the socket refuses one: how many it accepted."""
    sock.setblocking(False)
    for seq in range(limit):
        try:
            sock.send(frame(ident, struct.pack("<Q", seq)))
        except BlockingIOError:
            return seq
    return limit


def test_paused_sender_that_exits_loses_nothing(tmp_path):
    with OwnHub(tmp_path / "hub", "vcan0:bitrate=1000000") as hub:
        reader, high, flood = Client(hub.workdir), Client(hub.workdir), Client(hub.workdir)
        reader.bind(rcvbuf=8 << 20)
        high.bind()   # both senders receive each other's frames and never read them,
        flood.bind()  # as two can-load processes do
        sender = threading.Thread(target=send_all, args=(
            high.sock, [frame(HIGH_ID, struct.pack("<Q", seq)) for seq in range(HIGH_FRAMES)]))
        sender.start()

        def queued_for(client: Client) -> int:
            return next(c["queued"] for c in hub.stats()["clients"] if c["cookie"] == client.cookie)

        # the flood's socket is full of high frames and the hub queues more for it ...
        wait_for(lambda: queued_for(flood) > 0, "frames queued in the hub for the flood sender")
        # ... and the pending queue is full, so the hub pauses the flood after its first frames
        flooded = send_until_full(flood.sock, FLOOD_ID, FLOOD_FRAMES_MAX)
        flood.close()  # exits with frames written, unread by the paused hub
        sender.join(timeout=15)
        assert not sender.is_alive()
        high.close()

        counts = {HIGH_ID: 0, FLOOD_ID: 0}
        reader.sock.settimeout(3.0)  # the wire drains in well under a second
        try:
            while counts[HIGH_ID] < HIGH_FRAMES or counts[FLOOD_ID] < flooded:
                can_id, _, _ = CAN_FRAME.unpack(reader.sock.recv(8192)[:CAN_FRAME.size])
                counts[can_id] += 1
        except TimeoutError:
            pass
        iface = hub.stats()["interfaces"][0]
        assert counts == {HIGH_ID: HIGH_FRAMES, FLOOD_ID: flooded}, \
            f"reader got {counts} of {HIGH_FRAMES} high and {flooded} flood frames; " \
            f"the bus carried {iface['frames']}, rejected {iface['tx_rejects']}"
        assert iface["frames"] == HIGH_FRAMES + flooded
        assert hub.proc.poll() is None, hub.log.read_text()[-3000:]
