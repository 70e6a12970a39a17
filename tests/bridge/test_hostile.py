"""Hostile input on the bridge's tx key: a seeded campaign of CAMPAIGN_PAYLOADS
payloads (every length 0-64, a few large ones, frames with dlc > 8, reserved
and unknown flag bits, out-of-range ids, remote frames with data, random
bytes, mutations of valid frames, missing and garbage attachments), with a
valid marker frame after every MARKER_EVERY payloads. What must hold:

- exactly the payloads the bench's own decoder (canbench.wire, checked against
  the same golden vectors as the C decoder) accepts reach the bus, in order;
  nothing else ever does;
- every refusal is counted under the reason the bench expects;
- the bridge survives (its stats queryable answers, it exits 0 on SIGTERM) -
  under the ASan/UBSan build too, since `make check-bridge` runs this file
  against both builds.

The stats queryable also gets garbage (selectors, parameters, payloads) and
keeps answering, and a query with wildcards gets one reply per bridge, each on
its bridge's own key. Everything goes to loopback; the campaign is bounded."""
from __future__ import annotations

import json
import random
import signal
from collections import Counter

import zenoh
from conftest import Bridge, wait_for
from test_bridge_host import start_candump, stop_candump

from canbench import wire

CAMPAIGN_PAYLOADS = 100_000
MARKER_EVERY = 1000
SEED = 20261123
BATCH_LIMIT_FRAMES = 1024  # ZN_BATCH_MAX_FRAMES (zenoh_node.h): longer commands are refused as "length"
# ZN_RX_MESSAGE_MAX (docs/bridge.md): Zenoh drops a larger message before the bridge sees it
RX_MESSAGE_MAX = 32_780


def expected_outcome(payload: bytes, attachment: bytes | None) -> tuple[str, list[wire.Frame]]:
    """The reason the bridge must give ("ok" if valid, "unseen" if Zenoh drops it first) and the
    frames it must write."""
    if len(payload) > RX_MESSAGE_MAX:
        return "unseen", []
    if len(payload) > BATCH_LIMIT_FRAMES * wire.WIRE_SIZE:
        return "length", []
    try:
        frames = wire.decode_batch(payload)
    except wire.WireError as e:
        return e.reason, []
    if attachment is not None:
        try:
            meta = wire.decode_attachment(attachment)
        except wire.WireError:
            return "attachment", []
        if meta.count != len(frames):
            return "attachment", []
    return "ok", frames


def campaign(rng: random.Random):
    """(payload, attachment) pairs; deterministic for a seed."""
    valid = [wire.encode(wire.Frame(0x123, 4, b"\xde\xad\xbe\xef")),
             wire.encode(wire.Frame(0x1ABCDEF0, 8, bytes(range(8)), extended=True)),
             wire.encode(wire.Frame(0x7FF, 8, remote=True)), wire.encode(wire.Frame(0x0, 0))]
    for length in range(65):  # every length 0-64 of random bytes
        yield rng.randbytes(length), None
    for length in (1000, 16 * 1024, 16 * 1025, 65536):  # a few large ones, at and beyond the batch limit
        yield rng.randbytes(length), None
    targeted = [
        lambda f: f[:4] + bytes([rng.randint(9, 255)]) + f[5:],                          # dlc > 8
        lambda f: f[:5] + bytes([f[5] | rng.choice([0x04, 0x08, 0x80])]) + f[6:],       # unknown flag bits
        lambda f: f[:6] + rng.randbytes(2).replace(b"\0\0", b"\0\1") + f[8:],           # reserved bytes
        lambda f: (0x800 + rng.randint(0, 0xFFFF)).to_bytes(4, "little") + bytes([f[4], f[5] & ~1]) + f[6:],
        lambda f: (0x20000000 | rng.randint(0, 1 << 28)).to_bytes(4, "little") + f[4:5] + b"\x01" + f[6:],
        lambda f: wire.encode(wire.Frame(0x10, 2, remote=True))[:8] + rng.randbytes(8),  # remote with data
    ]
    n = 0
    while True:
        base = rng.choice(valid)
        kind = rng.random()
        if kind < 0.35:
            payload = rng.choice(targeted)(base)
        elif kind < 0.65:  # flip 1-3 random bits of 1-4 valid frames
            batch = bytearray(b"".join(rng.choice(valid) for _ in range(rng.randint(1, 4))))
            for _ in range(rng.randint(1, 3)):
                batch[rng.randrange(len(batch))] ^= 1 << rng.randrange(8)
            payload = bytes(batch)
        elif kind < 0.85:
            payload = rng.randbytes(rng.choice([16, 32, 48, rng.randint(0, 200)]))
        else:  # a valid payload with a missing, wrong or garbage attachment
            payload = b"".join(rng.choice(valid) for _ in range(rng.randint(1, 3)))
            count = len(payload) // 16
            yield payload, rng.choice([rng.randbytes(rng.randint(0, 40)),
                                       wire.encode_attachment(7, [1] * (count + 1)),
                                       b"\x02" + wire.encode_attachment(7, [1] * count)[1:]])
            n += 1
            continue
        yield payload, None
        n += 1


def test_hostile_commands_never_reach_the_bus_and_are_counted_by_reason(bus, bridge, session, tmp_path):
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log")
    rng = random.Random(SEED)
    # congestion control BLOCK: the campaign must arrive whole, never dropped by Zenoh
    publisher = session.declare_publisher("vehicle/can/tx", congestion_control=zenoh.CongestionControl.BLOCK)
    expected_bus: list[str] = []
    reasons: Counter = Counter()
    sent = 0
    marker_id = 0x700
    for payload, attachment in campaign(rng):
        reason, frames = expected_outcome(payload, attachment)
        reasons[reason] += 1
        expected_bus += [f.candump("vcan0") for f in frames]
        publisher.put(payload, attachment=attachment)
        sent += 1
        if sent % MARKER_EVERY == 0:  # valid frames that follow garbage still go through
            marker = wire.Frame(marker_id, 2, (sent // MARKER_EVERY).to_bytes(2, "big"))
            publisher.put(wire.encode(marker))
            reasons["ok"] += 1
            expected_bus.append(marker.candump("vcan0"))
        if sent >= CAMPAIGN_PAYLOADS:
            break
    total = sent - reasons["unseen"] + sent // MARKER_EVERY
    assert reasons["unseen"] == 1  # the 64 KiB payload: never reassembled, never counted
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_samples"] >= total and s,
                     f"the bridge to take all {total} commands", timeout=120)
    wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] >= len(expected_bus),
             "the valid frames written")
    on_bus = stop_candump(dump, out)
    # every valid frame once and nothing else; commands waiting together leave by CAN priority, those of
    # one id (the markers) in put order (docs/bridge.md)
    assert sorted(on_bus) == sorted(expected_bus), f"{len(on_bus)} frames on the bus, {len(expected_bus)} expected"
    markers = [wire.Frame(marker_id, 2, k.to_bytes(2, "big")).candump("vcan0")
               for k in range(1, sent // MARKER_EVERY + 1)]
    assert [line for line in on_bus if line in set(markers)] == markers
    rejected = {k: v for k, v in stats["tx_rejected"].items() if v}
    assert rejected == {k: v for k, v in reasons.items() if k not in ("ok", "unseen")}, (rejected, reasons)
    assert stats["can_tx_errors"] == 0
    # garbage at the stats queryable: it keeps answering
    for selector in ("vehicle/can/bridges/zenoh-node/stats?x=1;;;", "vehicle/can/bridges/*/stats?" + "a" * 2000):
        list(session.get(selector, payload=rng.randbytes(512)))
    assert bridge.stats(session)["buses"][0]["tx_samples"] == total
    rc, log = bridge.stop(signal.SIGTERM)
    assert rc == 0, log[-3000:]
    assert "ERROR: AddressSanitizer" not in log and "runtime error" not in log


def test_a_wildcard_stats_query_gets_each_bridge_on_its_own_key(bus, bridge, router, session):
    """The stats queryable replied on the query's key: to `vehicle/can/bridges/*/stats` (the bench's
    own query, canbench.runkeys.bridge_stats) every bridge answered on that same wildcard key, and
    the querier's consolidation kept one of the replies: one bridge's stats stood for all of them."""
    bridge.start("--can", "vcan0", "--name", "alpha")
    other = Bridge(bus, router)
    other.log = bus.workdir / "bridge-beta.log"
    other.start("--can", "vcan0", "--name", "beta")
    try:
        wait_for(lambda: len(bridge.wait_ready(session)) >= 2, "both bridges' tokens")
        for selector in ("vehicle/can/bridges/*/stats", "vehicle/can/bridges/**", "vehicle/can/**"):
            replies = [r.ok for r in session.get(selector) if r.ok]
            got = sorted((str(r.key_expr), json.loads(bytes(r.payload.to_bytes()))["node"]) for r in replies)
            assert got == [("vehicle/can/bridges/alpha/stats", "alpha"), ("vehicle/can/bridges/beta/stats", "beta")], \
                (selector, got)
    finally:
        rc, log = other.stop(signal.SIGTERM)
    assert rc == 0, log[-3000:]


def test_a_deletion_on_the_tx_key_is_no_command(bus, bridge, session):
    """session.delete on the tx key reached the bridge as a command of 0 bytes: counted in tx_samples and
    refused as tx_rejected.length, a reason that says nothing of what happened. A deletion carries no command."""
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    for _ in range(3):
        session.delete("vehicle/can/tx")
    marker = wire.Frame(0x321, 1, b"\x01")  # a command after them: once it is counted, the deletions were seen
    session.put("vehicle/can/tx", wire.encode(marker))
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_frames"] >= 1 and s,
                     "the command after the deletions written")
    assert stats["tx_samples"] == 1 and not any(stats["tx_rejected"].values()), stats
