"""Signal gates judged exactly, on what a frame carries (canbench/signals.py, dbc.raws_of): a
32-bit float's equals at its own width, a 64-bit integer to its last bit, a value-table name that
several values share, and a number between two values an integer signal carries refused at its
line. Seeded faults: each wrong frame fails its gate, every right one passes."""
from __future__ import annotations

from pathlib import Path

import cantools
import pytest
from synthetic import signal_problems

from canbench import oracle, scenario, wire
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

T0 = 1_700_000_000_000_000_000
DBC_TEXT = '''VERSION ""
BU_: ECU
BO_ 1585 Measure: 8 ECU
 SG_ Ratio : 0|32@1- (1,0) [0|0] "" ECU
BO_ 2147485000 Wide: 8 ECU
 SG_ Data : 0|64@1+ (1,0) [0|0] "" ECU
BO_ 1586 Cruise: 8 ECU
 SG_ State : 0|2@1+ (1,0) [0|0] "" ECU
 SG_ Volt : 8|8@1+ (0.5,-10) [0|0] "V" ECU
VAL_ 1586 State 1 "off" 0 "off" 2 "on" ;
SIG_VALTYPE_ 1585 Ratio : 1;
'''


def setup(tmp: Path, signals_yaml: str):
    (tmp / "x.dbc").write_text(DBC_TEXT)
    (tmp / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 631#0000000000000000\n")
    path = tmp / "sc.yaml"
    path.write_text("name: exact\nduration_s: 10\ndbc: x.dbc\nbuses:\n  - name: vcan0\n"
                    "ecus:\n  - name: e\n    bus: vcan0\n    trace: trace.log\nexpect:\n  signals:\n" + signals_yaml)
    db = cantools.database.load_file(str(tmp / "x.dbc"))
    return path, db


def frame(db, message: str, data: bytes | None = None, **values) -> wire.Frame:
    m = db.get_message_by_name(message)
    data = data if data is not None else bytes(m.encode(values, strict=False))
    return wire.Frame(m.frame_id, len(data), data, m.is_extended_frame)


def run(path: Path, frames: list[wire.Frame]):
    return signal_problems(path, frames)


def test_a_32_bit_float_equals_its_own_rounding_and_nothing_next_to_it(tmp_path):
    path, db = setup(tmp_path, "    Measure.Ratio: {equals: 1.1}\n")
    right = frame(db, "Measure", Ratio=1.1)  # CDCC8C3F: 1.1 as a 32-bit float
    assert right.data[:4] == bytes.fromhex("CDCC8C3F")
    assert run(path, [right, right]) == []
    next_float = frame(db, "Measure", data=bytes.fromhex("CECC8C3F00000000"))  # one unit in the last place
    problems = run(path, [right, next_float])
    assert len(problems) == 1 and "Measure.Ratio = 1.10000014, expected 1.1 at t=0.010 s, can.log:2" in problems[0]


def test_a_64_bit_integer_is_judged_to_its_last_bit(tmp_path):
    value = 18364758544493064720  # FEDCBA9876543210: past what a 64-bit float holds exactly
    path, db = setup(tmp_path, f"    Wide.Data: {{equals: {value}}}\n")
    right = frame(db, "Wide", Data=value)
    assert run(path, [right]) == []
    flipped = frame(db, "Wide", data=bytes([right.data[0] ^ 1]) + right.data[1:])
    problems = run(path, [right, flipped])
    assert len(problems) == 1
    assert f"Wide.Data = {value ^ 1}, expected {value} at t=0.010 s, can.log:2" in problems[0]


def test_a_name_several_values_share_stands_for_each_of_them(tmp_path):
    path, db = setup(tmp_path, "    Cruise.State: {one_of: ['off']}\n    Cruise.Volt: {range: [-10, 117.5]}\n")
    offs = [frame(db, "Cruise", State=0, Volt=0), frame(db, "Cruise", State=1, Volt=0)]
    assert run(path, offs) == []
    problems = run(path, offs + [frame(db, "Cruise", State=2, Volt=0)])
    assert len(problems) == 1 and "Cruise.State = 2 (on) not one of [off] at t=0.020 s, can.log:3" in problems[0]
    path, db = setup(tmp_path, "    Cruise.State: {equals: 'off'}\n")
    assert run(path, offs) == []
    problems = run(path, offs + [frame(db, "Cruise", State=2, Volt=0)])
    assert len(problems) == 1 and "expected off (each of the 2 values it names)" in problems[0]


def test_a_number_between_two_carried_values_is_refused_at_its_line(tmp_path):
    path, _ = setup(tmp_path, "    Cruise.Volt: {equals: 1.3}\n")
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    assert "sc.yaml:12: expect.signals.Cruise.Volt.equals: 1.3 is not a value Volt carries " \
           "(steps of 0.5 from -10): 1 or 1.5" in str(e.value)
    path, _ = setup(tmp_path, "    Cruise.Volt: {one_of: [1.5, -10]}\n")
    assert run(path, [frame(cantools.database.load_file(str(tmp_path / "x.dbc")), "Cruise", State=0, Volt=1.5)]) == []


def test_a_response_condition_is_as_exact_as_its_signal(tmp_path):
    """expect.responses' conditions alike: a 32-bit float's equals met by the frame that carries
    it, a name several values share met by each of them."""
    from canbench import responses
    from canbench.dbc import load_dbc
    (tmp_path / "x.dbc").write_text(DBC_TEXT)
    db = cantools.database.load_file(str(tmp_path / "x.dbc"))

    def rule(then: dict) -> responses.Rule:
        problems: list[str] = []
        doc = {"buses": [{"name": "vcan0"}],
               "expect": {"responses": [{"name": "r", "within_ms": 20, "then": then,
                                         "when": {"signal": "Cruise.Volt", "range": [0, 10]}}]}}
        out = responses.rules(doc, {"vcan0": tmp_path / "x.dbc"}, load_dbc, lambda where, m: problems.append(m))
        assert problems == []
        return out[0]

    def at(i: int, t_ms: float, f: wire.Frame) -> oracle.Observed:
        return oracle.Observed(f, int(t_ms * 1e6), i, line=i + 1, key="vehicle/can/rx", seq=i)

    stimulus = [at(0, 0, frame(db, "Cruise", State=2, Volt=-10)), at(1, 100, frame(db, "Cruise", State=2, Volt=5))]
    ratio = rule({"signal": "Measure.Ratio", "equals": 1.1})
    assert ratio.then.met(db.decode_message("Measure", frame(db, "Measure", Ratio=1.1).data)["Ratio"])
    out = responses.evaluate(ratio, [], stimulus, [at(0, 105, frame(db, "Measure", Ratio=1.1))])
    assert (out["answered"], out["problems"]) == (1, [])
    off = rule({"signal": "Cruise.State", "equals": "off", "side": "can"})
    assert off.then.met(0) and off.then.met(1) and not off.then.met(2)
