"""The bridge's command deadline (--tx-max-age-ms, docs/bridge.md "Freshness") against zenohd,
the bus and can-utils: a command whose attachment says it is older than the deadline is refused
whole and counted (tx_rejected.stale), never written, while a fresh one is written; the
attachment's time wins over the Zenoh timestamp the router gives the sample; with the deadline
off (0) the old command is written; and what a frozen router delivers late once it runs again is
refused: nothing reaches the bus older than the deadline."""
from __future__ import annotations

import signal
import time

from conftest import wait_for
from test_bridge_host import start_candump, stop_candump

from canbench import wire

MAX_AGE_MS = 100
MS = 1_000_000
WRITE_SLACK_MS = 20  # the age is judged when the transmitter takes the command; the bus stamp follows
PAUSE_PUTS, PAUSE_PERIOD_S = 20, 0.025  # 0.5 s of commands at 40 Hz into a frozen router


def put(session, can_id: int, data: bytes, source_ns: int | None, seq: int = 0) -> None:
    payload = wire.encode(wire.Frame(can_id, len(data), data))
    if source_ns is None:
        session.put("vehicle/can/tx", payload)
    else:
        session.put("vehicle/can/tx", payload, attachment=wire.encode_attachment(seq, [source_ns]))


def bus_frames(path) -> list[tuple[int, str]]:
    """(bus stamp ns, 'vcan0 ID#DATA') of each line of a candump -L log."""
    out = []
    for line in open(path).read().splitlines():
        if line.startswith("("):
            stamp, rest = line.split(" ", 1)
            sec, usec = stamp.strip("()").split(".")
            out.append((int(sec) * 1_000_000_000 + int(usec) * 1000, rest))
    return out


def test_a_stale_command_is_refused_and_counted_a_fresh_one_written(bus, bridge, session, tmp_path):
    bridge.start("--can", "vcan0", "--tx-max-age-ms", str(MAX_AGE_MS))
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log", frames=2)
    put(session, 0x100, b"\x01", time.time_ns() - 500 * MS)  # stamped 500 ms ago: the router stamps it fresh
    put(session, 0x101, b"\x02", time.time_ns(), seq=1)
    put(session, 0x102, b"\x03", None)  # no attachment: the sample's Zenoh timestamp decides
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_samples"] == 3 and
                     s["tx_frames"] + s["tx_rejected"]["stale"] == 3 and s, "three commands handled")
    assert stop_candump(dump, out) == ["vcan0 101#02", "vcan0 102#03"]
    assert stats["tx_rejected"]["stale"] == 1 and stats["tx_frames"] == 2, stats
    assert "refused a stale command" in bridge.log.read_text()


def test_with_the_deadline_off_an_old_command_is_written(bus, bridge, session, tmp_path):
    bridge.start("--can", "vcan0", "--tx-max-age-ms", "0")
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log", frames=1)
    put(session, 0x100, b"\x01", time.time_ns() - 5000 * MS)
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_frames"] == 1 and s, "the command")
    assert stop_candump(dump, out) == ["vcan0 100#01"]
    assert stats["tx_rejected"]["stale"] == 0


def test_what_a_frozen_router_delivers_late_is_refused(bus, bridge, router, session, tmp_path):
    bridge.start("--can", "vcan0", "--tx-max-age-ms", str(MAX_AGE_MS))
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log")
    puts = []
    assert router.proc is not None
    router.proc.send_signal(signal.SIGSTOP)
    try:
        for i in range(PAUSE_PUTS):
            puts.append(time.time_ns())
            put(session, 0x200 + i, bytes([i]), puts[-1], seq=i)
            time.sleep(PAUSE_PERIOD_S)  # pacing the commands, not synchronisation
    finally:
        resumed_ns = time.time_ns()
        router.proc.send_signal(signal.SIGCONT)
    # the link works again: a fresh command goes through, after what waited
    put(session, 0x7AB, b"\x01", time.time_ns(), seq=PAUSE_PUTS)
    wait_for(lambda: any(r.endswith("7AB#01") for _, r in bus_frames(out.name)), "a command after the pause on the bus")
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and
                     s["tx_frames"] + s["tx_rejected"]["stale"] >= PAUSE_PUTS and s, "the paused commands handled")
    stop_candump(dump, out)
    written = {int(r.split(" ")[1].split("#")[0], 16) - 0x200: t for t, r in bus_frames(out.name)
               if not r.endswith("7AB#01")}
    for i, bus_ns in written.items():  # nothing on the bus older than the deadline (and the write after it)
        age_ms = (bus_ns - puts[i]) / MS
        assert age_ms <= MAX_AGE_MS + WRITE_SLACK_MS, f"command {i} written {age_ms:.0f} ms after its put"
    # what waited in the frozen router was refused, each command once: written or counted
    late = sum(1 for t in puts if resumed_ns - t > (MAX_AGE_MS + WRITE_SLACK_MS) * MS)
    assert stats["tx_rejected"]["stale"] + len(written) == PAUSE_PUTS, (stats, sorted(written))
    assert stats["tx_rejected"]["stale"] >= late - 1, (stats, late)  # the first may pass before the router stops


def test_a_command_stamped_ahead_of_the_clock_is_refused(bus, bridge, session, tmp_path):
    """A source time further ahead of the bridge's clock than the deadline would never go stale,
    however late the command arrives (a sender's clock ahead, a forged stamp): refused on arrival,
    counted as tx_rejected.future. So is an attachment time beyond int64, which the bridge once
    replaced by the router's fresh Zenoh timestamp. One ahead by less than the deadline is written."""
    bridge.start("--can", "vcan0", "--tx-max-age-ms", str(MAX_AGE_MS))
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log", frames=1)
    hour_ns = 3600 * 1000 * MS
    put(session, 0x100, b"\x01", time.time_ns() + hour_ns)
    put(session, 0x101, b"\x02", 1 << 63)
    put(session, 0x102, b"\x03", (1 << 64) - 1)
    put(session, 0x103, b"\x04", time.time_ns() + MAX_AGE_MS * MS // 2)
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_samples"] == 4 and
                     s["tx_frames"] + s["tx_rejected"].get("future", 0) == 4 and s, "four commands handled")
    assert stop_candump(dump, out) == ["vcan0 103#04"]
    assert stats["tx_rejected"]["future"] == 3 and stats["tx_rejected"]["stale"] == 0, stats
    assert "ahead of this clock" in bridge.log.read_text()
