"""Traffic both ways at once over mutual TLS loses nothing and keeps the bridge's one connection.
Zenoh 1.10.2's published TLS link read and wrote one rustls stream from two tasks at once: a write
failed ("handshake not complete"), the link closed and was replaced within milliseconds, and the
samples put meanwhile vanished though their put returned Ok (docs/bridge.md, "Samples lost on a TLS
link"). The bench builds with the link's stream split (firmware/ports/linux/zenoh_rust/patched/):
here CAN frames flow to Zenoh while commands flow to CAN, and every frame must arrive, numbered
without a gap, with connections_closed 0."""
from __future__ import annotations

import json
import threading
import time

import zenoh
from conftest import wait_for
from test_access import _nest, client_config, make_ca, make_cert, tls_creds

from canbench import wire

# Measured with the published crate in the bridge: its connection closed in the first round of
# each of 8 runs (frames and commands lost); the patched build: none in 40 rounds.
ROUNDS = 2
FRAMES = 10000       # CAN -> Zenoh a round, cangen at the pace below
COMMANDS = 10000     # Zenoh -> CAN a round, at the same pace: both directions busy at once, within
                     # what the 2-core machine's bus and bridge carry (no queue of theirs overflows)
GAP_MS = "0.3"       # cangen's gap: about 3 000 frames/s for 3 s
COMMAND_GAP_S = 0.0003


def test_duplex_traffic_over_mutual_tls_loses_nothing(bus, bridge, router, tmp_path):
    d = tmp_path / "pki"
    d.mkdir()
    make_ca(d, "ca")
    for cn in ("router", "bridge", "peer"):
        make_cert(d, "ca", cn)
    router.stop()
    router.endpoint = router.endpoint.replace("tcp/", "tls/")
    config = {"transport": {"link": {"tls": {"root_ca_certificate": str(d / "ca.pem"),
                                             "listen_certificate": str(d / "router.pem"),
                                             "listen_private_key": str(d / "router.key"),
                                             "enable_mtls": True}}}}
    (tmp_path / "router.json5").write_text(json.dumps(config))
    router.start("--config", str(tmp_path / "router.json5"))
    bridge_conf = tmp_path / "bridge-zenoh.json5"
    bridge_conf.write_text(json.dumps(_nest(tls_creds(d, "bridge"))))
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--zenoh-config", str(bridge_conf))
    session = zenoh.open(client_config(router.endpoint, tls_creds(d, "peer")))
    try:
        bridge.wait_ready(session)
        seqs: list[int] = []
        loaded: list[wire.Frame] = []  # cangen's (the bridge may also read the commands it wrote)
        lock = threading.Lock()

        def on_rx(sample) -> None:
            att = wire.decode_attachment(sample.attachment.to_bytes())
            frames = wire.decode_batch(sample.payload.to_bytes())
            with lock:
                seqs.extend(range(att.first_seq, att.first_seq + att.count))
                loaded.extend(f for f in frames if f.can_id == 0x123)
        sub = session.declare_subscriber("vehicle/can/rx", on_rx)
        pub = session.declare_publisher("vehicle/can/tx")
        for r in range(1, ROUNDS + 1):
            load = bus.popen(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", GAP_MS, "-n", str(FRAMES)])
            start = time.monotonic()
            for i in range(COMMANDS):
                pub.put(wire.encode(wire.Frame(0x100, 2, i.to_bytes(2, "little"))))
                if i % 32 == 31 and (ahead := start + i * COMMAND_GAP_S - time.monotonic()) > 0:
                    time.sleep(ahead)  # pacing the load
            assert load.wait(timeout=60) == 0

            def done(r: int = r) -> bool:  # or a connection closed: its loss is said below, not waited for
                s = bridge.stats(session)
                return s["connections_closed"] > 0 or (s["buses"][0]["tx_samples"] >= r * COMMANDS
                                                        and len(loaded) >= r * FRAMES
                                                        and len(seqs) >= s["buses"][0]["published_frames"])
            try:
                wait_for(done, f"every command at the bridge and every frame from it (round {r})", timeout=30)
            except TimeoutError as e:
                raise AssertionError(f"{e}: {len(loaded)} of {r * FRAMES} frames, {len(seqs)} numbers, "
                                     f"{bridge.stats(session)}; the hub: {bus.stats() if bus.hub else None}") from None
            stats = bridge.stats(session)
            if stats["connections_closed"]:
                break
        sub.undeclare()
    finally:
        session.close()
    s = stats["buses"][0]
    assert stats["connections_closed"] == 0 and stats["reconnects"] == 0, \
        f"the bridge's connection closed under duplex traffic in round {r}: {len(loaded)} of {r * FRAMES} frames " \
        f"and {s['tx_samples']} of {r * COMMANDS} commands arrived; {stats}"
    assert s["tx_samples"] == ROUNDS * COMMANDS, s
    assert s["published_frames"] == s["can_rx_frames"] - s["filtered"], s
    assert sorted(seqs) == list(range(s["published_frames"])), \
        f"{s['published_frames'] - len(set(seqs))} of {s['published_frames']} sequence numbers missing"
    assert len(loaded) == ROUNDS * FRAMES, len(loaded)
