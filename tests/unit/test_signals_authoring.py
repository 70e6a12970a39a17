"""Authoring with a DBC: `canbench summarise --dbc` (per-message signal statistics of a trace:
scaled, multiplexed and value-table signals, ids the DBC lacks, frames that do not decode) and
`canbench scaffold --dbc` (the DBC copied next to the scenario, cycle_time.from_dbc, proposed
signal gates marked for review that the trace itself passes)."""
from __future__ import annotations

import pytest
from test_signals import DBC, T0, frame

from canbench import authoring, cli, dbc, oracle, scenario, signals, wire

pytestmark = pytest.mark.unit


def write_trace(path, extra: list[tuple[int, wire.Frame]] = ()) -> None:
    frames = []
    for i in range(100):
        frames.append((i * 10, frame("EngineData", Counter=i % 16, EngineSpeed=800 + 22 * i, EngineTorque=-20 + i)))
        if i % 5 == 0:
            frames.append((i * 10 + 1, frame("GearboxState", Gear=0 if i < 50 else 3, GearboxOilPressure=2.5)))
        if i % 10 == 0:
            frames.append((i * 10 + 2, frame("Diag", Page=(i // 10) % 2, CoolantTemp=80 + i // 10,
                                             OilPressure=300 + i)))
    frames += list(extra)
    frames.sort(key=lambda x: x[0])
    with open(path, "w") as f:
        for ms, fr in frames:
            t = T0 + ms * 1_000_000
            f.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {fr.candump('vcan0')}\n")


def test_summary_of_signals_per_message(tmp_path):
    trace = tmp_path / "drive.log"
    write_trace(trace, [(5, wire.Frame(0x7DF, 2, b"\x01\x02")), (6, wire.Frame(0x0C0, 2, b"\x00\x01"))])
    s = authoring.summarise_signals(trace, DBC)
    by_name = {m.name: m for m in s.messages}
    assert s.unknown_ids == {"7DF": 1}
    engine = by_name["EngineData"]
    assert (engine.frames, engine.undecodable, engine.cycle_ms) == (101, 1, 10.0)
    speed = engine.signals["EngineSpeed"]
    assert (speed.count, speed.min, speed.max, speed.unit) == (100, 800.0, 800.0 + 22 * 99, "rpm")
    assert engine.signals["EngineTorque"].min == -20.0  # offset -125 applied
    assert by_name["GearboxState"].signals["Gear"].names == {"P", "D"}
    diag = by_name["Diag"].signals  # multiplexed: each signal only in its page
    assert diag["CoolantTemp"].count == 5 and diag["OilPressure"].count == 5
    assert diag["OilPressure"].min == 310.0
    table = s.table()
    assert "EngineData (0C0): 101 frames, DBC cycle 10 ms, 1 undecodable" in table
    assert "1 frames of 1 ids it lacks (7DF)" in table
    assert "['D', 'P']" in table


def test_cli_summarise_with_a_dbc(tmp_path, capsys):
    trace = tmp_path / "drive.log"
    write_trace(trace)
    assert cli.main(["summarise", str(trace), "--dbc", str(DBC)]) == 0
    out = capsys.readouterr().out
    assert "bus load" in out and "signals decoded with" in out and "EngineSpeed" in out


def test_scaffold_with_a_dbc_proposes_gates_the_trace_passes(tmp_path):
    trace = tmp_path / "recorded" / "drive.log"
    trace.parent.mkdir()
    write_trace(trace)
    out = tmp_path / "scenarios" / "drive.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "drive", "--out", str(out), "--dbc", str(DBC)]) == 0
    text = out.read_text()
    assert "# PROPOSED, REVIEW EACH" in text and text.count("# review: ") >= 8
    sc = scenario.load(out)
    assert sc.dbc == (tmp_path / "scenarios" / "dbc" / "signals.dbc").resolve()
    # Diag goes every 100 ms in the recording, its DBC says 200: the recording's cycle, said for review
    assert sc.expect["cycle_time"] == {"from_dbc": True, "tolerance_pct": 20, "ids": {"400": 100.0}}
    assert "# REVIEW: the trace's cycle in cycle_time.ids where it is not the DBC's +-20%: 400 every 100 ms " \
           "(the DBC: 200)." in text
    gates = {g.key: g for g in sc.signal_gates}
    assert gates["GearboxState.Gear"].one_of == (3.0, 0.0)  # the names seen: D, P
    low, high = gates["EngineData.EngineSpeed"].range
    assert low < 800 and high > 800 + 22 * 99 and high - low == pytest.approx(1.2 * 22 * 99, rel=1e-3)
    assert gates["EngineData.Counter"].range == (0.0, 15.0)  # widened, then within the DBC's [0|15]
    # the trace it came from meets every proposal
    evaluator = signals.Evaluator(sc.signal_gates, dbc.load_dbc(sc.dbc), "can", "vcan0", T0)
    for o in oracle.read_candump(sc.ecus[0].trace, "vcan0"):
        evaluator.feed(o.frame, o.t_ns, f"can.log:{o.line}")
    series = evaluator.finish()
    assert len(series) == len(sc.signal_gates) and all(s.violation_count == 0 for s in series)
