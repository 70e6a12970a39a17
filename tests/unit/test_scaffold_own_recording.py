"""A scenario scaffolded with a DBC passes the recording it was made from, on recordings as real cars
and loggers make them (found on public recordings of 20 cars): an odometer that barely moves (its
range was rounded into its own values), a message recorded at two lengths (its short frames do not
decode), one id at two cycles on two interfaces, an id sent twice a cycle under one logger stamp
(from_dbc judged both against the DBC's one cycle)."""
from __future__ import annotations

from pathlib import Path

import pytest
from test_scaffold_cycle_gates import T0, judged

from canbench import authoring, cli, dbc, oracle, scenario, signals

pytestmark = pytest.mark.unit

HEAD = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\n'
CYCLES = ('BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;\nBA_DEF_DEF_ "GenMsgCycleTime" 0;\n'
          'BA_ "GenMsgCycleTime" BO_ 256 10;\nBA_ "GenMsgCycleTime" BO_ 768 10;\n')
DBC = HEAD + '''BO_ 256 Odometer: 8 ECU
 SG_ Km : 0|32@1+ (0.1,0) [0|429496729.5] "km" Vector__XXX
 SG_ Counter : 32|4@1+ (1,0) [0|15] "" Vector__XXX

BO_ 768 Status: 4 ECU
 SG_ Mode : 0|8@1+ (1,0) [0|255] "" Vector__XXX

''' + CYCLES


def line(t_ns: int, iface: str, text: str) -> str:
    return f"({t_ns // 10**9}.{t_ns % 10**9 // 1000:06d}) {iface} {text}\n"


def scaffold(tmp: Path, lines: list[str]) -> tuple[Path, str]:
    (tmp / "car.dbc").write_text(DBC)
    trace = tmp / "rec.log"
    trace.write_text("".join(lines))
    out = tmp / "rec.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "rec", "--out", str(out), "--dbc", str(tmp / "car.dbc")]) == 0
    return out, out.read_text()


def odometer(i: int, km10: int) -> str:
    return "100#" + (km10.to_bytes(4, "little") + bytes([i % 16, 0, 0, 0])).hex().upper()


def passes_its_signal_gates(sc) -> bool:
    evaluator = signals.Evaluator(sc.signal_gates, dbc.load_dbc(sc.dbc), "can", "vcan0", T0)
    for o in oracle.read_candump(sc.ecus[0].trace, "vcan0"):
        evaluator.feed(o.frame, o.t_ns, f"can.log:{o.line}")
    return all(s.violation_count == 0 for s in evaluator.finish())


def test_a_range_of_values_of_more_than_six_digits_holds_them(tmp_path):
    # 123456.7 .. 123456.8 km: rounded to the nearest 6 digits, [123457, 123457] held neither
    out, _ = scaffold(tmp_path, [line(T0 + i * 10_000_000, "can0", odometer(i, 1234567 + i // 50)) for i in range(100)])
    sc = scenario.load(out)
    low, high = {g.key: g for g in sc.signal_gates}["Odometer.Km"].range
    assert low <= 123456.7 and high >= 123456.8
    assert passes_its_signal_gates(sc)


def test_a_message_recorded_shorter_than_its_dbc_length_is_not_gated(tmp_path):
    # Status is 4 bytes in the DBC; some of its frames are 2: a gate counted each a violation
    rec = [line(T0 + i * 10_000_000, "can0", "300#0102" if i % 3 else "300#01020304") for i in range(60)]
    out, text = scaffold(tmp_path, rec)
    assert ("# Status.Mode: {present: 1}  # review: not gated: 40 of Status's 60 frames do not decode with the "
            "DBC (a length other than its 4 bytes?)") in text
    sc = scenario.load(out)
    assert "Status.Mode" not in {g.key for g in sc.signal_gates}
    summary = authoring.summarise(tmp_path / "rec.log")
    assert "300       60  2-4" in summary.table()  # the dlc column shows both lengths


def test_an_id_sent_twice_a_cycle_under_one_stamp_passes_its_replay_with_a_dbc(tmp_path):
    # 300 twice every 10 ms under one stamp: its median gap is 0, from_dbc judged it against 10 ms
    frames = sorted([(T0 + i * 10_000_000, odometer(i, 5)) for i in range(200)]
                    + [(T0 + i * 10_000_000 + 2_000_000, f"300#{k:02X}000000") for i in range(200) for k in (0, 1)])
    out, text = scaffold(tmp_path, [line(t, "can0", x) for t, x in frames])
    sc = scenario.load(out)
    assert "from_dbc" not in sc.expect["cycle_time"] and "Not cycle_time.from_dbc: the trace sends 300" in text
    assert judged(sc, tmp_path, frames) == []
    # the seeded fault still fails it: 100 (gated at its cycle) never arrives
    assert judged(sc, tmp_path, [f for f in frames if not f[1].startswith("100#")]) != []


def test_an_id_of_two_cycles_on_two_interfaces_is_not_judged_against_the_dbcs_one(tmp_path):
    rec = sorted([(T0 + i * 10_000_000, "can0", odometer(i, 5)) for i in range(100)]
                 + [(T0 + i * 20_000_000 + 1_000_000, "can1", odometer(i, 5)) for i in range(50)]
                 + [(T0 + i * 10_000_000 + 2_000_000, iface, "300#01020304") for i in range(100)
                    for iface in ("can0", "can1")])
    out, text = scaffold(tmp_path, [line(t, i, x) for t, i, x in rec])
    sc = scenario.load(out)
    cycle = sc.expect["cycle_time"]
    assert "from_dbc" not in cycle and "100" not in cycle.get("ids", {}) and cycle["ids"]["300"] == 10.0
    assert "Not cycle_time.from_dbc: the trace sends 100 at no one cycle on every interface" in text
