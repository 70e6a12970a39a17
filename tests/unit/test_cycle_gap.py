"""cycle_time's largest gap is the gap the bridge adds, not the bus's: a frame its ECU sent late
(a gap on the bus, carried as is) passes, the bridge holding a frame back (a gap on Zenoh only)
fails with both numbers. Seeded runs: the powertrain capture, its Zenoh copy written by hand."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from canbench import checks, oracle, run, scenario, wire
from canbench.capture import Sample, format_sample_line

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
TRACE = REPO / "scenarios" / "traces" / "powertrain-2s.log"
GATE = {"cycle_time": {"ids": {"0C0": 10}, "max_gap_factor": 2}}


def seeded(tmp_path: Path, *, bus_late_ms: float = 0, zenoh_late_ms: float = 0) -> run.RunResult:
    """From 0x0C0's 100th frame on, everything later by bus_late_ms on the bus (its ECU stalled) or by
    zenoh_late_ms on Zenoh only (the bridge stalled)."""
    sc = scenario.load(REPO / "scenarios" / "smoke.yaml")
    sc = dataclasses.replace(sc, expect={**sc.expect, **GATE})
    frames = oracle.read_candump(TRACE, "vcan0")
    late = [i for i, o in enumerate(frames) if o.frame.can_id == 0x0C0][100]
    bus_t = [o.t_ns + (int(bus_late_ms * 1e6) if i >= late else 0) for i, o in enumerate(frames)]
    with open(tmp_path / "can.log", "w") as f:
        for o, t in zip(frames, bus_t, strict=True):
            f.write(f"({t // 1_000_000_000}.{t % 1_000_000_000 // 1000:06d}) {o.frame.candump('vcan0')}\n")
    with open(tmp_path / "zenoh.tsv", "w") as f:
        for i, (o, t) in enumerate(zip(frames, bus_t, strict=True)):
            at = t + 400_000 + (int(zenoh_late_ms * 1e6) if i >= late else 0)
            f.write(format_sample_line(Sample(at, "vehicle/can/rx", wire.encode(o.frame),
                                              wire.encode_attachment(i, [t]))))
    return run.analyse(sc, "seeded", tmp_path, "vehicle/can", {}, None, 2.0)


def test_on_time_passes(tmp_path):
    assert checks.cycle_time(seeded(tmp_path)) == []


def test_a_gap_the_bus_had_is_not_the_bridges(tmp_path):
    r = seeded(tmp_path, bus_late_ms=15)
    assert r.buses[0].cycle_times["0C0"]["zenoh"]["cycle_max_ms"] == pytest.approx(25, abs=0.01)
    assert checks.cycle_time(r) == []


def test_a_gap_the_bridge_adds_fails_with_its_numbers(tmp_path):
    r = seeded(tmp_path, zenoh_late_ms=15)
    assert checks.cycle_time(r) == ["vcan0 id 0C0: a gap 15.00 ms longer on Zenoh than on the bus (longest on Zenoh "
                                    "25.00 ms), more than (2 - 1) x 10.00 ms"]
