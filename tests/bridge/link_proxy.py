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

# the router's InitAck and OpenAck (or a Close refusing the link), each framed as a universal batch:
# zenoh 1.10.2 sends OpenAck once the link is added, before the low-latency transport's first write
HANDSHAKE_MESSAGES = 2
MAX_MESSAGE = 65_535  # Zenoh's largest batch: a longer length means the proxy lost the stream's framing
KEEPALIVE_MAX = 8  # bytes of a framed keep-alive, at most: a fault replaces a larger message (a command)
PAUSE_S = 0.0003  # between some pieces, so that the reader takes a piece before the next comes


@dataclass(frozen=True)
class Fault:
    """Bytes written to the bridge in place of the router's next message (a keep-alive passes);
    then_close: end the connection after them (else the bridge must find the stream bad and close
    it itself)."""
    data: bytes
    then_close: bool


class Framer:
    """Splits a stream into whole framed messages, however its reads cut it."""

    def __init__(self, low_latency: bool):
        self.low_latency = low_latency
        self.buf = bytearray()
        self.messages_seen = 0

    def length_size(self) -> int:
        return 4 if self.low_latency and self.messages_seen >= HANDSHAKE_MESSAGES else 2

    def feed(self, data: bytes) -> list[bytes]:
        self.buf += data
        out = []
        while len(self.buf) >= self.length_size():
            size = self.length_size()
            end = size + int.from_bytes(self.buf[:size], "little")
            if end - size > MAX_MESSAGE:
                raise ValueError(f"a message of {end - size} bytes: the proxy lost the stream's framing")
            if len(self.buf) < end:
                break
            out.append(bytes(self.buf[:end]))
            del self.buf[:end]
            self.messages_seen += 1
        return out


class LinkProxy:
    """Listens on a free loopback port (endpoint) and links each connection to the router's port.
    cut: the router's stream, and the bridge's, go on in random pieces (1 byte to a few messages;
    each stream's sizes from its own generator, seeded by the connection and the direction), some
    after a short pause. arm(fault): the router's next message (not a keep-alive) is replaced."""

    def __init__(self, router_port: int, low_latency: bool, cut: bool, seed: int):
        self.router_port, self.low_latency, self.cut, self.seed = router_port, low_latency, cut, seed
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.endpoint = f"tcp/127.0.0.1:{self.listener.getsockname()[1]}"
        self.lock = threading.Lock()
        self.connections = 0
        self.fault: Fault | None = None
        self.injected_at: float | None = None  # when the armed fault went to the bridge
        self.bridge_closed_at: dict[int, float] = {}  # connection number: when its bridge side ended
        self.errors: list[str] = []
        self.events: list[str] = []  # what happened to each connection, for a failing test's report
        self.started = time.monotonic()
        self.sockets: list[socket.socket] = []
        self.threads: list[threading.Thread] = []
        self.stopping = False
        self._spawn(self._accept)

    def note(self, what: str) -> None:
        self.events.append(f"{time.monotonic() - self.started:.3f} s: {what}")

    def arm(self, fault: Fault) -> None:
        with self.lock:
            self.fault = fault

    def stop(self) -> None:
        self.stopping = True
        with self.lock:
            sockets = [self.listener, *self.sockets]
        self._close(*sockets)
        for s in sockets:
            s.close()
        for t in self.threads:  # each ends once its sockets are shut; the events are then complete
            t.join(timeout=5)

    def _spawn(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        self.threads.append(t)
        t.start()

    def _accept(self) -> None:
        while not self.stopping:
            try:
                bridge, _ = self.listener.accept()
            except OSError as e:
                if not self.stopping:
                    self.note(f"accepting no more connections: {e}")
                return
            try:
                router = socket.create_connection(("127.0.0.1", self.router_port))
            except OSError as e:  # the bridge tries again: so does the proxy, with its next connection
                self.note(f"no connection to the router: {e}")
                bridge.close()
                continue
            for s in (bridge, router):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.lock:
                self.connections += 1
                self.sockets += [bridge, router]
                number = self.connections
            self.note(f"connection {number} opened")
            self._spawn(self._to_router, bridge, router, number)
            self._spawn(self._to_bridge, router, bridge, number)

    def _send(self, dst: socket.socket, data: bytes, rng: random.Random) -> None:
        """data whole, or (cut) in pieces of 1-3 bytes, 4-40 or up to 200, half of them after a pause."""
        while data:
            size = len(data)
            if self.cut:
                size = rng.choice((rng.randint(1, 3), rng.randint(4, 40), rng.randint(41, 200)))
                if rng.random() < 0.5:
                    time.sleep(PAUSE_S)  # pacing, not synchronisation: the reader may well take two pieces at once
            dst.sendall(data[:size])
            data = data[size:]

    def _to_router(self, bridge: socket.socket, router: socket.socket, number: int) -> None:
        rng = random.Random(f"{self.seed}/{number}/to-router")
        why = "the bridge closed it"
        try:
            while data := bridge.recv(65536):
                self._send(router, data, rng)
        except OSError as e:  # a reset too: the bridge closed the link with the router's bytes unread
            why = f"{e} on the bridge's side"
        self.bridge_closed_at[number] = time.monotonic()
        self.note(f"connection {number}: {why}")
        self._close(bridge, router)

    def _take_fault(self, messages: list[bytes]) -> Fault | None:
        """The armed fault, if these messages hold one it may replace (more than keep-alives)."""
        with self.lock:
            fault = self.fault
            if fault is None or all(len(m) <= KEEPALIVE_MAX for m in messages):
                return None
            self.fault = None
            return fault

    def _to_bridge(self, router: socket.socket, bridge: socket.socket, number: int) -> None:
        rng = random.Random(f"{self.seed}/{number}/to-bridge")
        why = "the router closed it"
        framer = Framer(self.low_latency)
        try:
            while data := router.recv(65536):
                messages = framer.feed(data)
                fault = self._take_fault(messages)
                if fault is None:
                    self._send(bridge, b"".join(messages), rng)
                    continue
                bridge.sendall(fault.data)
                self.injected_at = time.monotonic()
                why = f"fault written: {fault}"
                if fault.then_close:
                    break
                while router.recv(65536):  # the bridge must close this link: the router's messages go nowhere
                    pass
                break
        except ValueError as e:
            self.errors.append(str(e))
            why = str(e)
        except OSError as e:
            why = f"{e} on the router's side"
        self.note(f"connection {number}: {why}")
        self._close(router, bridge)

    @staticmethod
    def _close(*sockets: socket.socket) -> None:
        for s in sockets:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
