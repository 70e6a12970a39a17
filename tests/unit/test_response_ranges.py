"""A value a signal can never carry, in expect.responses (then/when equals, one_of, range, a
command's signals) or as a restbus/command value: outside the DBC's minimum and maximum, or
outside what its bits encode at its scale and offset where the DBC gives no limits ([0|0]) or
wider ones. Each is a problem at its file:line naming the signal, the value and the range, from
canbench validate (exit 2), never a check that cannot pass or a frame cantools wraps silently."""
from __future__ import annotations

import textwrap
from pathlib import Path

import cantools
import pytest

from canbench import dbc, validate

pytestmark = pytest.mark.unit

DBC = """\
VERSION ""

NS_ :

BS_:

BU_: TESTER ECU

BO_ 256 Req: 8 TESTER
 SG_ ReqVal : 0|16@1- (0.1,0) [-1000|1000] "Nm" ECU

BO_ 257 Resp: 8 ECU
 SG_ RespVal : 0|16@1- (0.1,0) [-1000|1000] "Nm" TESTER
 SG_ Raw8 : 16|8@1+ (0.5,-10) [0|0] "V" TESTER
 SG_ Wide : 24|8@1+ (1,0) [0|300] "" TESTER
 SG_ Flt : 32|32@1- (1,0) [0|0] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 256 100;
BA_ "GenMsgCycleTime" BO_ 257 100;

SIG_VALTYPE_ 257 Flt : 1;
"""

HEAD = """\
name: ranges
duration_s: 10
dbc: r.dbc
buses: [{name: vcan0}]
commands: [{bus: vcan0, message: Req, signals: {ReqVal: 50}, run_s: 1}]
ecus: [{name: ecu, bus: vcan0, role: responder, rules: [{request: Req, send: Resp, set: {RespVal: ReqVal}}]}]
"""


def problems(tmp_path: Path, body: str) -> list[str]:
    (tmp_path / "r.dbc").write_text(DBC)
    path = tmp_path / "s.yaml"
    path.write_text(HEAD + textwrap.dedent(body))
    return [str(p).removeprefix(f"{path}:") for p in validate.problems(path)]


def response(when: str, then: str) -> str:
    return f"expect:\n  responses:\n    - {{when: {when}, then: {then}, within_ms: 50}}\n"


@pytest.mark.parametrize("then,said", [
    ("{signal: Resp.RespVal, equals: 1500}", "then.equals: 1500 is outside RespVal's range [-1000, 1000] Nm"),
    ("{signal: Resp.RespVal, one_of: [50, -2000]}",
     "then.one_of.1: -2000 is outside RespVal's range [-1000, 1000] Nm"),
    ("{signal: Resp.RespVal, range: [2000, 3000]}",
     "then.range: [2000, 3000] is outside RespVal's range [-1000, 1000] Nm: no value meets it"),
    ("{signal: Resp.RespVal, range: [5, 1]}", "then.range: min 5 is above max 1"),
    ("{signal: Resp.Raw8, equals: 120}",  # no DBC limits: what 8 bits at scale 0.5, offset -10 carry
     "then.equals: 120 is outside Raw8's range [-10, 117.5] V (what its 8 bits at scale 0.5, offset -10 carry: "
     "[-10, 117.5])"),
    ("{signal: Resp.Wide, equals: 256}",  # the DBC's limits wider than the signal's 8 bits
     "then.equals: 256 is outside Wide's range [0, 255] (the DBC's [0|300] and what its 8 bits at scale 1, "
     "offset 0 carry: [0, 255])"),
])
def test_a_response_value_the_signal_cannot_carry_fails_validation(tmp_path, then, said):
    assert problems(tmp_path, response("{command: Req}", then)) == [f"9: expect.responses.0.{said}"]


def test_a_stimulus_value_the_signal_cannot_carry_fails_validation(tmp_path):
    found = problems(tmp_path, response("{command: Req, signals: {ReqVal: 1000.5}}", "{signal: Resp.RespVal}"))
    assert found == ["9: expect.responses.0.when.signals.ReqVal: 1000.5 is outside ReqVal's range [-1000, 1000] Nm"]
    found = problems(tmp_path, response("{signal: Resp.Raw8, equals: -11}", "{signal: Resp.RespVal}"))
    assert found == ["9: expect.responses.0.when.equals: -11 is outside Raw8's range [-10, 117.5] V "
                     "(what its 8 bits at scale 0.5, offset -10 carry: [-10, 117.5])"]


def test_values_at_the_ends_and_ranges_that_overlap_pass(tmp_path):
    body = ("expect:\n  responses:\n"
            "    - {when: {command: Req, signals: {ReqVal: -1000}}, then: {signal: Resp.RespVal, equals: 1000},"
            " within_ms: 50}\n"
            "    - {when: {command: Req}, then: {signal: Resp.RespVal, range: [900, 5000]}, within_ms: 50}\n"
            "    - {when: {command: Req}, then: {signal: Resp.Raw8, one_of: [-10, 117.5]}, within_ms: 50}\n"
            "    - {when: {command: Req}, then: {signal: Resp.Flt, equals: 1.0e+30}, within_ms: 50}\n")
    assert problems(tmp_path, body) == []


def test_a_value_the_bits_cannot_carry_is_refused_before_the_run(tmp_path):
    # Raw8 = 200 is raw 420 in 8 bits: validate said ok, then every answer raised OverflowError in
    # cantools, which the responder counts as an undecodable request: nothing answered, no word why
    (tmp_path / "r.dbc").write_text(DBC)
    path = tmp_path / "s.yaml"
    path.write_text(HEAD.replace("set: {RespVal: ReqVal}", "set: {RespVal: ReqVal, Raw8: 200}")
                    + "expect: {integrity: true}\n")
    assert [str(p) for p in validate.problems(path)] == [
        f"{path}:6: ecus.0.rules.0.set.Raw8: 200 is outside Raw8's range [-10, 117.5] V (what its 8 bits at "
        "scale 0.5, offset -10 carry: [-10, 117.5])"]


def test_value_range_of_float_and_limited_signals():
    resp = cantools.database.load_string(DBC).get_message_by_name("Resp")
    assert dbc.value_range(resp.get_signal_by_name("RespVal")) == (-1000, 1000, "")
    # a 32-bit float carries up to its largest finite value (above it cantools would send inf)
    assert dbc.value_range(resp.get_signal_by_name("Flt"))[:2] == (-dbc.FLOAT32_MAX, dbc.FLOAT32_MAX)
    assert dbc.range_problem(resp.get_signal_by_name("Raw8"), 117.5) is None  # 255 * 0.5 - 10


@pytest.mark.parametrize("gate,said", [
    ("{equals: 1500}", "Resp.RespVal.equals: 1500 is outside RespVal's range [-1000, 1000] Nm"),
    ("{one_of: [0, -2000]}", "Resp.RespVal.one_of.1: -2000 is outside RespVal's range [-1000, 1000] Nm"),
    ("{range: [2000, 3000]}",
     "Resp.RespVal.range: [2000, 3000] is outside RespVal's range [-1000, 1000] Nm: every frame would fail it"),
])
def test_a_signal_gate_no_frame_can_meet_fails_validation(tmp_path, gate, said):
    # expect.signals: a value or band the signal never carries is a gate that can only fail
    assert problems(tmp_path, f"expect:\n  signals:\n    Resp.RespVal: {gate}\n") == [f"9: expect.signals.{said}"]


def test_a_signal_gate_overlapping_the_range_passes(tmp_path):
    body = "expect:\n  signals:\n    Resp.RespVal: {range: [900, 5000]}\n    Resp.Raw8: {one_of: [-10, 117.5]}\n"
    assert problems(tmp_path, body) == []
