"""A TCP proxy on loopback between the bridge and its router that delivers the router's byte stream
as a network may: cut anywhere and joined across messages, or corrupted at a message boundary. It
reads Zenoh's stream framing (a little-endian length before each message: 2 bytes for the
handshake and the universal transport's batches, 4 bytes for the low-latency transport's messages
after the handshake), so a fault lands between two messages, where a reader trusts the length."""
from __future__ import annotations

import random
import socket
import threading
import time
from dataclasses import dataclass

HANDSHAKE_MESSAGES = 2  # the router's InitAck and OpenAck, each framed as a universal batch
MAX_MESSAGE = 65_535  # Zenoh's largest batch: a longer length means the proxy lost the framing
PAUSE_S = 0.0003  # between some pieces, so that the reader takes a piece before the next comes


@dataclass(frozen=True)
class Fault:
    """Bytes written to the bridge in place of the router's next message; close: end the connection
    after them (else the bridge must find the stream bad and close it itself)."""
    data: bytes
    close: bool


class Framer:
    """Splits a stream into whole framed messages, however its reads cut it."""

    def __init__(self, long_lengths: bool):
        self.long_lengths = long_lengths
        self.buf = bytearray()
        self.seen = 0

    def prefix(self) -> int:
        return 4 if self.long_lengths and self.seen >= HANDSHAKE_MESSAGES else 2

    def feed(self, data: bytes) -> list[bytes]:
        self.buf += data
        out = []
        while len(self.buf) >= self.prefix():
            size = self.prefix()
            end = size + int.from_bytes(self.buf[:size], "little")
            if end - size > MAX_MESSAGE:
                raise ValueError(f"a message of {end - size} bytes: the proxy lost the stream's framing")
            if len(self.buf) < end:
                break
            out.append(bytes(self.buf[:end]))
            del self.buf[:end]
            self.seen += 1
        return out


class LinkProxy:
    """Listens on a free loopback port (endpoint) and links each connection to the router's port.
    cut: the router's stream, and the bridge's, go on in random pieces (1 byte to a few messages,
    seeded), some after a short pause. arm(fault): the next message from the router is replaced."""

    def __init__(self, router_port: int, low_latency: bool, cut: bool, seed: int):
        self.router_port, self.low_latency, self.cut = router_port, low_latency, cut
        self.rng = random.Random(seed)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.endpoint = f"tcp/127.0.0.1:{self.listener.getsockname()[1]}"
        self.lock = threading.Lock()
        self.connections = 0
        self.fault: Fault | None = None
        self.injected = threading.Event()
        self.errors: list[str] = []
        self.events: list[str] = []  # what happened to each connection, for a failing test's message
        self.started = time.monotonic()
        self.sockets: list[socket.socket] = []
        self.stopping = False
        threading.Thread(target=self._accept, daemon=True).start()

    def note(self, what: str) -> None:
        self.events.append(f"{time.monotonic() - self.started:.3f} s: {what}")

    def arm(self, fault: Fault) -> None:
        with self.lock:
            self.fault = fault

    def stop(self) -> None:
        self.stopping = True
        for s in [self.listener, *self.sockets]:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def _accept(self) -> None:
        while not self.stopping:
            try:
                bridge, _ = self.listener.accept()
                router = socket.create_connection(("127.0.0.1", self.router_port))
            except OSError as e:
                if not self.stopping:
                    self.note(f"accepting no more connections: {e}")
                return
            for s in (bridge, router):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.lock:
                self.connections += 1
                self.sockets += [bridge, router]
                n = self.connections
            self.note(f"connection {n} opened")
            threading.Thread(target=self._to_router, args=(bridge, router, n), daemon=True).start()
            threading.Thread(target=self._to_bridge, args=(router, bridge, n), daemon=True).start()

    def _send(self, dst: socket.socket, data: bytes) -> None:
        """data whole, or (cut) in pieces of 1-3 bytes, 4-40 or up to 200, half of them after a pause."""
        while data:
            n = len(data)
            if self.cut:
                with self.lock:
                    n = self.rng.choice((self.rng.randint(1, 3), self.rng.randint(4, 40), self.rng.randint(41, 200)))
                    pause = self.rng.random() < 0.5
                if pause:
                    time.sleep(PAUSE_S)  # pacing, not synchronisation: the reader may well take two pieces at once
            dst.sendall(data[:n])
            data = data[n:]

    def _to_router(self, bridge: socket.socket, router: socket.socket, n: int) -> None:
        why = "the bridge closed it"
        try:
            while data := bridge.recv(65536):
                self._send(router, data)
        except OSError as e:
            why = f"{e} on the bridge's side"
        self.note(f"connection {n}: {why}")
        self._close(bridge, router)

    def _to_bridge(self, router: socket.socket, bridge: socket.socket, n: int) -> None:
        why = "the router closed it"
        framer = Framer(self.low_latency)
        try:
            while data := router.recv(65536):
                messages = framer.feed(data)
                with self.lock:
                    fault, self.fault = (self.fault, None) if messages else (None, self.fault)
                if fault is None:
                    self._send(bridge, b"".join(messages))
                    continue
                bridge.sendall(fault.data)
                self.injected.set()
                why = f"fault written: {fault}"
                if fault.close:
                    break
                while router.recv(65536):  # the bridge must close this link: the router's messages go nowhere
                    pass
                break
        except ValueError as e:
            self.errors.append(str(e))
            why = str(e)
        except OSError as e:
            why = f"{e} on the router's side"
        self.note(f"connection {n}: {why}")
        self._close(router, bridge)

    @staticmethod
    def _close(*sockets: socket.socket) -> None:
        for s in sockets:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
