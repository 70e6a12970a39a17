"""Scaffolded cycle gates judged on a faithful replay and on seeded faults, on traffic as real cars
and loggers make it: an id the gate names that never comes, an id sent twice a cycle under one
stamp, a bridge that holds one id back at random (jitter)."""
from __future__ import annotations

import dataclasses
import random
from pathlib import Path

import pytest

from canbench import analysis, checks, cli, scenario, wire
from canbench.capture import Sample, format_sample_line
from canbench.trace import iter_candump

pytestmark = pytest.mark.unit
T0 = 1_700_000_000_000_000_000


def judged(sc, tmp: Path, frames, latency=lambda i: 400_000) -> list[str]:
    """cycle_time on a run whose bus carried frames [(t_ns, candump id#data)] on vcan0 and whose
    bridge forwarded each in order after latency(i) (never before the one before it)."""
    at, zen = 0, []
    with open(tmp / "can.log", "w") as bus:
        for i, (t, text) in enumerate(frames):
            bus.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) vcan0 {text}\n")
            at = max(at, t + latency(i))
            zen.append((at, i, t, text))
    parsed = [f for _, _, _, f in iter_candump(tmp / "can.log")]
    with open(tmp / "zenoh.tsv", "w") as out:
        for (a, i, t, _), f in zip(zen, parsed, strict=True):
            out.write(format_sample_line(Sample(a, "vehicle/can/rx", wire.encode(f), wire.encode_attachment(i, [t]))))
    return checks.cycle_time(analysis.analyse(sc, "r", tmp, "vehicle/can", {}, None, 5.0))


def scaffolded(tmp: Path, frames) -> scenario.Scenario:
    trace = tmp / "rec.log"
    trace.write_text("".join(f"({t // 10**9}.{t % 10**9 // 1000:06d}) can0 {x}\n" for t, x in frames))
    assert cli.main(["scaffold", str(trace), "--name", "rec", "--out", str(tmp / "rec.yaml")]) == 0
    return scenario.load(tmp / "rec.yaml")


def test_a_gated_id_that_never_comes_fails_cycle_time(tmp_path):
    rec = sorted([(T0 + i * 10_000_000, "100#00") for i in range(200)]
                 + [(T0 + i * 20_000_000 + 1_000_000, "200#00") for i in range(100)])
    sc = scaffolded(tmp_path, rec)
    assert sc.expect["cycle_time"]["ids"] == {"100": 10.0, "200": 20.0}
    assert judged(sc, tmp_path, rec) == []
    # the seeded fault: 200 never on the bus (its ECU silent), so never on Zenoh either
    assert judged(sc, tmp_path, [f for f in rec if not f[1].startswith("200#")]) != []


def test_an_id_sent_twice_per_cycle_with_one_stamp_passes_a_faithful_replay(tmp_path):
    # a logger's one stamp for the frames it took together: 300 twice every 10 ms, 100 every 10 ms
    rec = sorted([(T0 + i * 10_000_000, "100#00") for i in range(200)]
                 + [(T0 + i * 10_000_000 + 2_000_000, f"300#{k:02X}") for i in range(200) for k in (0, 1)])
    sc = scaffolded(tmp_path, rec)
    assert "300" not in sc.expect["cycle_time"]["ids"]  # not periodic: not gated ...
    jitter = [200_000 + (i * 7919) % 400_000 for i in range(len(rec))]  # 0.2 .. 0.6 ms, in order
    assert judged(sc, tmp_path, rec, latency=lambda i: jitter[i]) == []  # ... nor failed on its median 0


def test_max_jitter_added_ms_fails_a_bridge_that_holds_one_id_back_at_random(tmp_path):
    # id 100 held back 0.4 to 4.9 ms at random, in order: its gaps 5.5 to 14.5 ms on Zenoh against
    # 10.0 on the bus, nothing lost or reordered, its median cycle and the median latency as before
    rec = sorted([(T0 + i * 10_000_000, "100#00") for i in range(300)]
                 + [(T0 + i * 10_000_000 + 5_000_000, "200#11") for i in range(300)])
    sc = scaffolded(tmp_path, rec)
    gated = dataclasses.replace(sc, expect={**sc.expect, "cycle_time": {**sc.expect["cycle_time"],
                                                                       "max_jitter_added_ms": 1.0}})
    rng = random.Random(0)
    held = [400_000 + (rng.randrange(4_500_000) if text.startswith("100#") else 0) for _, text in rec]
    assert judged(sc, tmp_path, rec, latency=lambda i: held[i]) == []  # the median gates see nothing
    [problem] = judged(gated, tmp_path, rec, latency=lambda i: held[i])
    assert problem.startswith("vcan0 id 100: its gaps spread ") and "more than max_jitter_added_ms 1" in problem
    faithful = [200_000 + (i * 7919) % 400_000 for i in range(len(rec))]  # 0.2 .. 0.6 ms, in order
    assert judged(gated, tmp_path, rec, latency=lambda i: faithful[i]) == []


def test_a_bridge_that_delivers_each_burst_of_a_bursty_id_at_once_fails_cycle_time(tmp_path):
    # 300 in bursts of 5 frames 10 ms apart every 500 ms: not periodic, held to the bus's median
    # 10 ms (its mean gap 100 ms must not widen the tolerance); the bridge holds each burst and
    # publishes it at once: Zenoh's median gap 0, nothing lost or reordered
    ms = 1_000_000
    rec = sorted([(T0 + i * 10 * ms, "100#00") for i in range(500)]
                 + [(T0 + b * 500 * ms + k * 10 * ms + 3 * ms, f"300#{k:02X}") for b in range(10) for k in range(5)])
    sc = scaffolded(tmp_path, rec)
    assert "300" not in sc.expect["cycle_time"]["ids"]
    assert judged(sc, tmp_path, rec) == []

    def held(i: int) -> int:
        t, text = rec[i]
        return 400_000 if not text.startswith("300#") else \
            T0 + (t - T0) // (500 * ms) * 500 * ms + 43 * ms - t + 400_000
    assert any(p.startswith("vcan0 id 300: median cycle") for p in judged(sc, tmp_path, rec, latency=held))


def test_one_late_wakeup_on_an_id_of_few_gaps_does_not_fail_the_jitter_gate(tmp_path):
    # 200 once a second for 6 s: 5 gaps, whose 10th and 90th percentiles are their min and max
    ms = 1_000_000
    rec = sorted([(T0 + i * 10 * ms, "100#00") for i in range(600)]
                 + [(T0 + i * 1000 * ms + 5 * ms, "200#00") for i in range(6)])
    sc = scaffolded(tmp_path, rec)
    gated = dataclasses.replace(sc, expect={**sc.expect, "cycle_time": {**sc.expect["cycle_time"],
                                                                       "max_jitter_added_ms": 3.0}})
    late = next(i for i, (_, x) in enumerate(rec) if x.startswith("200#") and i > len(rec) // 2)
    faithful = [200_000 + (i * 7919) % 400_000 + (4 * ms if i == late else 0) for i in range(len(rec))]
    assert judged(gated, tmp_path, rec, latency=lambda i: faithful[i]) == []
