"""Help for writing scenarios from a recorded trace: a per-id summary (count,
rate, inferred cycle time, jitter, bus load) and a scenario scaffold that
replays the trace with gates derived from it."""
from __future__ import annotations

import os
import shutil
import statistics
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import yaml

from .trace import read_trace
from .wire import id_hex

# An id is periodic when nearly all its gaps sit near the median gap: a median alone
# (or its absolute deviation) also "finds" a cycle in two interleaved streams of one id
# (gaps 1, 9, 1, 9 ms) or in bursts, and a gate on such a median flips with one frame.
STEADY_PCT = 10  # a gap within +-10 % of the cycle is steady
PERIODIC_STEADY_PCT = 90  # ... and an id with at least 90 % steady gaps is periodic


def frame_bits_worst(dlc: int, extended: bool, remote: bool = False) -> int:
    """Worst-case stuffed length of a classic CAN frame incl. 3 bits interframe space
    (Davis, Burns et al., 'CAN schedulability analysis revisited')."""
    n = 0 if remote else dlc
    return (8 * n + 64 + (54 + 8 * n - 1) // 4 if extended else 8 * n + 44 + (34 + 8 * n - 1) // 4) + 3


@dataclass
class IdSummary:
    ident: str
    extended: bool
    count: int
    dlc: int
    cycle_ms: float | None
    jitter_ms: float | None  # median absolute deviation of the gaps
    remote: int
    steady_pct: float | None = None  # share of the gaps within STEADY_PCT of the cycle


@dataclass
class TraceSummary:
    path: Path
    frames: int
    span_s: float
    interfaces: list[str]
    ids: list[IdSummary]
    load_pct: float
    bitrate: int

    def table(self) -> str:
        lines = [f"{self.path}: {self.frames} frames over {self.span_s:.3f} s on {', '.join(self.interfaces)}; "
                 f"bus load {self.load_pct:.1f}% of {self.bitrate // 1000} kbit/s (worst-case stuffing)",
                 f"  {'id':>8}  {'frames':>7}  {'dlc':>3}  {'cycle ms':>9}  {'jitter ms':>9}  {'steady %':>8}  remote"]
        for s in self.ids:
            cycle = f"{s.cycle_ms:9.2f}" if s.cycle_ms is not None else f"{'-':>9}"
            jitter = f"{s.jitter_ms:9.3f}" if s.jitter_ms is not None else f"{'-':>9}"
            steady = f"{s.steady_pct:8.0f}" if s.steady_pct is not None else f"{'-':>8}"
            lines.append(f"  {s.ident:>8}  {s.count:>7}  {s.dlc:>3}  {cycle}  {jitter}  {steady}  {s.remote}")
        return "\n".join(lines)


def summarise(path: Path, bitrate: int = 500_000) -> TraceSummary:
    frames = read_trace(path)
    by_id: dict[tuple, list] = defaultdict(list)
    bits = 0
    for tf in frames:
        m = tf.message
        by_id[(m.arbitration_id, m.is_extended_id)].append(m)
        bits += frame_bits_worst(m.dlc, m.is_extended_id, m.is_remote_frame)
    span = frames[-1].message.timestamp - frames[0].message.timestamp
    ids = []
    for (can_id, extended), msgs in sorted(by_id.items()):
        gaps = [(b.timestamp - a.timestamp) * 1000 for a, b in zip(msgs, msgs[1:], strict=False)]
        cycle = statistics.median(gaps) if gaps else None
        jitter = statistics.median(abs(g - cycle) for g in gaps) if gaps and cycle is not None else None
        steady = (100 * sum(abs(g - cycle) <= cycle * STEADY_PCT / 100 for g in gaps) / len(gaps)
                  if gaps and cycle else None)
        ids.append(IdSummary(id_hex(can_id, extended), extended, len(msgs),
                             max(m.dlc for m in msgs), cycle, jitter, sum(m.is_remote_frame for m in msgs), steady))
    interfaces = sorted({str(tf.message.channel) for tf in frames if tf.message.channel is not None})
    return TraceSummary(path, len(frames), span, interfaces or ["vcan0"], ids,
                        100 * bits / bitrate / span if span > 0 else 0.0, bitrate)


def scaffold(trace: Path, name: str, scenario_path: Path, bitrate: int = 500_000) -> str:
    """A scenario replaying the trace, with gates a first run should pass; YAML text.
    The bench mounts only the scenario's directory into its containers, so a trace from
    elsewhere is copied to <scenario dir>/traces/."""
    s = summarise(trace, bitrate)
    home = scenario_path.resolve().parent
    if not trace.resolve().is_relative_to(home):
        copy = home / "traces" / trace.name
        copy.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(trace, copy)
        trace = copy
    # The replay ECU sends every frame of its trace on its one bus: a trace of several
    # interfaces is replayed merged, and its cycles are inferred from the merged stream.
    bus = s.interfaces[0] if len(s.interfaces) == 1 and s.interfaces[0].startswith("vcan") else "vcan0"
    merged = (f"# The trace's interfaces {', '.join(s.interfaces)} are replayed merged onto {bus} "
              f"(one replay ECU, one bus).\n" if len(s.interfaces) > 1 else "")
    periodic = [i for i in s.ids if i.cycle_ms and i.count >= 5 and i.steady_pct is not None
                and i.steady_pct >= PERIODIC_STEADY_PCT]
    doc = {
        "name": name,
        "description": f"Replay of {trace.name} ({s.frames} frames, {s.span_s:.1f} s, "
                       f"{len(s.ids)} ids, {s.load_pct:.0f}% load at {bitrate // 1000} kbit/s).",
        "duration_s": max(10, int(s.span_s * 1.5) + 5),
        "buses": [{"name": bus}],
        "ecus": [{"name": "recorded", "bus": bus,
                  "trace": os.path.relpath(trace.resolve(), home)}],
        "bridge": {"mode": "client", "publish_period_ms": 0},
        "expect": {
            "integrity": True, "ordering": True, "loss_budget": 0,
            "latency": {"can_to_zenoh": {"p50_ms": 5, "max_regression_pct": 50}},
            "cycle_time": {"tolerance_pct": 20,
                           "ids": {i.ident: round(i.cycle_ms, 3) for i in periodic if i.cycle_ms is not None}},
        },
    }
    header = (f"# Scaffolded by `canbench scaffold` from {trace.name}: review the gates, then run\n"
              f"#   make test SCENARIO={scenario_path}\n"
              f"{merged}"
              f"# Periodic ids (cycle inferred from the trace, >= {PERIODIC_STEADY_PCT}% of the gaps within "
              f"+-{STEADY_PCT}% of it) are gated in cycle_time.ids.\n")
    return header + yaml.safe_dump(doc, sort_keys=False)

