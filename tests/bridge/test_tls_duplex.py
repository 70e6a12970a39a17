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

import zenoh
from conftest import wait_for
from test_access import _nest, client_config, make_ca, make_cert, tls_creds

from canbench import wire

FRAMES = 6000        # CAN -> Zenoh, cangen at its fastest pace below
COMMANDS = 6000      # Zenoh -> CAN, put as fast as the session takes them
GAP_MS = "0.3"       # cangen's gap: about 3 000 frames/s for 2 s


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
        load = bus.popen(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", GAP_MS, "-n", str(FRAMES)])
        pub = session.declare_publisher("vehicle/can/tx")
        for i in range(COMMANDS):
            pub.put(wire.encode(wire.Frame(0x100, 2, i.to_bytes(2, "little"))))
        assert load.wait(timeout=60) == 0
        wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] >= COMMANDS, "the commands on the bus")
        wait_for(lambda: len(loaded) >= FRAMES, "every frame from the bridge", timeout=30)
        stats = bridge.stats(session)
        wait_for(lambda: len(seqs) >= stats["buses"][0]["published_frames"], "every sample the bridge put")
        sub.undeclare()
    finally:
        session.close()
    s = stats["buses"][0]
    assert s["published_frames"] == s["can_rx_frames"] - s["filtered"], s
    assert sorted(seqs) == list(range(s["published_frames"])), \
        f"{s['published_frames'] - len(set(seqs))} of {s['published_frames']} sequence numbers missing"
    assert len(loaded) == FRAMES, len(loaded)
    assert stats["connections_closed"] == 0 and stats["reconnects"] == 0, stats
