"""The orchestrator's commands carry the bridge's attachment (canbench/commands.py): one frame, its
sequence number per bus, and its source time, the put time logged in commands.tsv less the entry's
stamp_age_ms. The bridge's deadline is judged on that time (docs/bridge.md, Freshness)."""
from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from canbench import commands, oracle, scenario, wire

pytestmark = pytest.mark.unit
STALE = Path(__file__).resolve().parents[2] / "scenarios" / "stale-commands.yaml"


class Publisher:
    def __init__(self, puts: list):
        self.puts = puts

    def put(self, payload: bytes, attachment: bytes | None = None) -> None:
        self.puts.append((payload, attachment))

    def undeclare(self) -> None:
        pass


class Reply:
    """A stats reply: the bridge counted every command put so far (tx_samples)."""

    def __init__(self, samples: int):
        self.ok = self
        self.payload = self
        self.text = json.dumps({"buses": [{"bus": "vcan0", "tx_samples": samples}]}).encode()

    def to_bytes(self) -> bytes:
        return self.text


class Session:
    def __init__(self):
        self.puts: list = []
        self.gets: list[str] = []

    def declare_publisher(self, key: str) -> Publisher:
        return Publisher(self.puts)

    def get(self, key: str, timeout: float | None = None) -> list[Reply]:
        self.gets.append(key)
        return [Reply(len(self.puts))]


def test_every_command_carries_its_source_time_and_sequence(tmp_path):
    sc = scenario.load(STALE)
    session = Session()
    commander = commands.Commander(session, sc, tmp_path / "commands.tsv")  # type: ignore[arg-type]
    commander.items = commander.items[:40]  # the first 0.4 s: both entries
    commander.run()
    assert commander.error is None
    logged = oracle.read_sent_log(tmp_path / "commands.tsv")
    assert len(logged) == len(session.puts) == 40
    seqs = []
    for (payload, att), row in zip(session.puts, logged, strict=True):
        frame, a = wire.decode(payload), wire.decode_attachment(att)
        assert frame == row.frame and a.count == 1
        age_ms = (row.t_ns - a.rx_times_ns[0]) / 1e6
        assert age_ms == (400 if frame.can_id == 0x6B0 else 0), (frame, age_ms)
        seqs.append(a.first_seq)
    assert seqs == list(range(40))  # one bus: numbered in put order
    assert commands.stale_at_put(sc) == {("vcan0", 0x6B0, False)}
    # the fence: one stats query after the last put, which counted all 40
    assert session.gets == ["vehicle/can/bridges/*/stats"]
    arrived = commands.read_arrivals(tmp_path / "commands.tsv")
    assert logged[-1].t_ns <= arrived["vcan0"] <= time.time_ns()
