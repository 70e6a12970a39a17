"""Stimulus-response checks on hand-made series: answers on time, late, missing, early (before
the stimulus) and duplicated; stimuli counted; a bus-signal stimulus fires on its edge only;
each problem names the stimulus (commands.tsv:line or can.log:line) and what was seen instead."""
from __future__ import annotations

from pathlib import Path

import cantools
import pytest

from canbench import responses
from canbench.dbc import load_dbc
from canbench.oracle import Observed
from canbench.wire import Frame

pytestmark = pytest.mark.unit

DBC = Path(__file__).resolve().parents[2] / "scenarios" / "dbc" / "powertrain.dbc"
DB = cantools.database.load_file(str(DBC))
REQ, RESP = DB.get_message_by_name("TorqueRequest"), DB.get_message_by_name("TorqueResponse")
BODY = DB.get_message_by_name("BodyStatus")
MS = 1_000_000


def doc(when: dict, then: dict, **extra) -> dict:
    return {"buses": [{"name": "vcan0"}], "commands": [{"bus": "vcan0", "message": "TorqueRequest", "run_s": 1}],
            "expect": {"responses": [{"name": "torque", "when": when, "then": then, "within_ms": 20, **extra}]}}


def rule(when=None, then=None, **extra) -> responses.Rule:
    problems: list[str] = []
    out = responses.rules(doc(when or {"command": "TorqueRequest", "signals": {"TorqueRequested": 50}},
                              then or {"signal": "TorqueResponse.TorqueActual", "equals": 50}, **extra),
                          {"vcan0": DBC}, load_dbc, lambda where, m: problems.append(m))
    assert problems == []
    return out[0]


def put(i: int, t_ms: float, torque: float) -> Observed:
    data = REQ.encode({"RequestCounter": i % 16, "TorqueRequested": torque, "RequestChecksum": 0})
    return Observed(Frame(0x100, 8, data), int(t_ms * MS), i, line=i + 2, origin="commands.tsv")


def answer(i: int, t_ms: float, torque: float) -> Observed:
    data = RESP.encode({"ResponseCounter": 0, "TorqueActual": torque, "ResponseCrc": 0})
    return Observed(Frame(0x101, 8, data), int(t_ms * MS), i, key="vehicle/can/rx", seq=i)


def body(i: int, t_ms: float, locked: int) -> Observed:
    data = BODY.encode({"BodyCounter": 0, "DoorsLocked": locked, "AmbientTemp": 20, "BodyChecksum": 0})
    return Observed(Frame(0x320, 8, data), int(t_ms * MS), i, line=i + 1)


def test_answers_on_time_give_the_latency_distribution():
    r = rule(count=2)
    out = responses.evaluate(r, [put(0, 100, 50), put(1, 200, 50), put(2, 300, -3)], [],
                             [answer(0, 103, 50), answer(1, 205.5, 50), answer(2, 301, -3)])
    assert out["problems"] == []
    assert (out["stimuli"], out["answered"], out["late"], out["missing"]) == (2, 2, 0, 0)
    assert out["latency"]["min_ms"] == pytest.approx(3.0) and out["latency"]["max_ms"] == pytest.approx(5.5)


def test_a_late_answer_names_the_stimulus_and_its_latency():
    out = responses.evaluate(rule(), [put(0, 100, 50)], [], [answer(0, 104, 49), answer(1, 135, 50)])
    assert (out["answered"], out["late"], out["missing"]) == (0, 1, 0)
    [problem] = out["problems"]
    assert problem.startswith("torque: TorqueRequest {TorqueRequested = 50} put at commands.tsv:2: "
                              "TorqueResponse.TorqueActual == 50 late, after 35.000 ms (within 20 ms) (zenoh #1)")
    assert "before it: 49 at +4.000 ms (zenoh #0)" in problem
    [only] = responses.evaluate(rule(), [put(0, 100, 50)], [], [answer(1, 135, 50)])["problems"]
    assert only.endswith("late, after 35.000 ms (within 20 ms) (zenoh #1)")  # nothing before it


def test_a_missing_answer_says_what_was_seen_instead():
    out = responses.evaluate(rule(), [put(0, 100, 50)], [], [answer(0, 104, 49.5)])
    assert (out["answered"], out["missing"]) == (0, 1)
    assert out["problems"] == ["torque: TorqueRequest {TorqueRequested = 50} put at commands.tsv:2: no "
                               "TorqueResponse.TorqueActual == 50 within 20 ms; seen instead: 49.5 at +4.000 ms "
                               "(zenoh #0)"]
    nothing = responses.evaluate(rule(), [put(0, 100, 50)], [], [])
    assert nothing["problems"][0].endswith("no TorqueResponse frame within 20 ms")


def test_an_early_answer_is_no_answer_and_is_named():
    """An answer before its request (stale, or a responder that does not wait): not counted."""
    out = responses.evaluate(rule(), [put(0, 100, 50)], [], [answer(0, 95, 50)])
    assert (out["answered"], out["missing"]) == (0, 1)
    assert "a matching one came before the stimulus: 50 at -5.000 ms (zenoh #0)" in out["problems"][0]


def test_duplicate_answers_fail_once_and_each_frame_belongs_to_the_latest_stimulus():
    stimuli = [put(0, 100, 50), put(1, 200, 50)]
    seen = [answer(0, 102, 50), answer(1, 104, 50), answer(2, 203, 50)]
    once = responses.evaluate(rule(once=True), stimuli, [], seen)
    assert (once["answered"], once["duplicates"]) == (2, 1)
    assert once["problems"] == ["torque: TorqueRequest {TorqueRequested = 50} put at commands.tsv:2: 2 responses "
                                "TorqueResponse.TorqueActual == 50, once expected: 50 at +2.000 ms (zenoh #0), "
                                "50 at +4.000 ms (zenoh #1)"]
    # a cyclic response (not once): more frames meeting the condition are no problem
    assert responses.evaluate(rule(), stimuli, [], seen)["problems"] == []


def test_stimuli_are_counted_and_filtered_by_their_signals():
    r = rule(count=3)
    out = responses.evaluate(r, [put(0, 100, 50), put(1, 200, 10)], [], [answer(0, 101, 50), answer(1, 201, 10)])
    assert out["stimuli"] == 1  # the put with TorqueRequested 10 is not this rule's stimulus
    assert out["problems"] == ["torque: 1 stimuli (TorqueRequest {TorqueRequested = 50} put), 3 expected: "
                               "commands.tsv:2"]
    none = responses.evaluate(rule(), [put(1, 200, 10)], [], [])
    assert none["problems"] == ["torque: no stimulus: nothing TorqueRequest {TorqueRequested = 50} put, "
                                "so nothing judged"]


def test_a_bus_signal_stimulus_fires_when_the_condition_starts_to_hold():
    r = rule(when={"signal": "BodyStatus.DoorsLocked", "equals": "Unlocked"},
             then={"signal": "TorqueResponse.TorqueActual", "range": [-1, 1]})
    bus = [body(0, 0, 1), body(1, 50, 0), body(2, 100, 0), body(3, 150, 1), body(4, 200, 0)]
    out = responses.evaluate(r, [], bus, [answer(0, 60, 0), answer(1, 230, 0)])
    assert out["stimuli"] == 2 and out["answered"] == 1 and out["late"] == 1
    assert out["problems"][0].startswith("torque: BodyStatus.DoorsLocked == Unlocked on the bus at can.log:5: "
                                         "TorqueResponse.TorqueActual in [-1, 1] late, after 30.000 ms")


def test_unknown_names_are_problems():
    problems: list[tuple] = []
    bad = doc({"command": "TorqueRequests"}, {"signal": "TorqueResponse.Torque", "equals": 1})
    bad["expect"]["responses"] += [{"when": {"command": "TorqueRequest", "signals": {"Torque": 1}},
                                    "then": {"signal": "BodyStatus.DoorsLocked", "equals": "Open"}, "within_ms": 5},
                                   {"when": {"command": "PedalData"},
                                    "then": {"signal": "TorqueResponse.TorqueActual"}, "within_ms": 5}]
    responses.rules(bad, {"vcan0": DBC}, load_dbc, lambda where, m: problems.append((".".join(map(str, where)), m)))
    where = [w for w, _ in problems]
    assert where == ["expect.responses.0.then.signal", "expect.responses.1.then.equals",
                     "expect.responses.1.when.signals.Torque", "expect.responses.2.when.command"]
    assert problems[1][1] == "'Open' is not in DoorsLocked's value table ['Unlocked', 'Locked']"
    assert "no command puts PedalData on vcan0" in problems[3][1]


def test_readmes_scenario_shows_a_response_check_that_loads():
    """README's scenario (Writing a scenario) carries a response check on the shipped DBC."""
    import yaml
    text = (Path(__file__).resolve().parents[2] / "README.md").read_text().split("\n## Writing a scenario\n", 1)[1]
    doc = yaml.safe_load(text.split("```yaml\n", 1)[1].split("```", 1)[0])
    problems: list[str] = []
    [r] = responses.rules(doc, {"vcan0": DBC}, load_dbc, lambda where, m: problems.append(m))
    assert problems == [] and r.command.name == "TorqueRequest" and r.once
    assert {e["role"] for e in doc["ecus"] if "role" in e} >= {"restbus", "responder"}


def test_side_can_looks_for_the_response_on_the_bus():
    r = rule(then={"signal": "TorqueResponse.TorqueActual", "equals": 50, "side": "can"})
    on_bus = [Observed(answer(0, 103, 50).frame, 103 * MS, 0, line=7)]
    out = responses.evaluate(r, [put(0, 100, 50)], on_bus, [])
    assert (out["answered"], out["side"]) == (1, "can") and out["latency"]["p50_ms"] == pytest.approx(3.0)
    assert responses.evaluate(r, [put(0, 100, 50)], [], on_bus)["missing"] == 1  # Zenoh's frames are not looked at


def test_a_stimulus_signal_the_command_lacks_is_a_problem():
    problems: list[tuple] = []
    bad = doc({"command": "TorqueRequest", "signals": {"Torque": 1}}, {"signal": "TorqueResponse.TorqueActual"})
    responses.rules(bad, {"vcan0": DBC}, load_dbc, lambda where, m: problems.append((".".join(map(str, where)), m)))
    assert problems == [("expect.responses.0.when.signals.Torque",
                         "TorqueRequest has no signal 'Torque' (it has ['RequestChecksum', 'RequestCounter', "
                         "'TorqueRequested'])")]


def test_an_infinite_within_ms_is_a_problem_at_its_line(tmp_path):
    # the schema took YAML's .inf; the analysis then stopped on int(inf) and wrote no report at all
    from canbench import scenario
    from canbench.errors import ScenarioError
    (tmp_path / "t.log").write_text("(1700000000.000000) vcan0 123#00\n")
    path = tmp_path / "r.yaml"
    path.write_text(f"name: r\nduration_s: 5\ndbc: {DBC}\nbuses: [{{name: vcan0}}]\n"
                    "ecus: [{name: e, bus: vcan0, trace: t.log}]\n"
                    "commands: [{bus: vcan0, message: TorqueRequest, run_s: 1}]\n"
                    "expect:\n  responses:\n    - when: {command: TorqueRequest}\n"
                    "      then: {signal: TorqueResponse.TorqueActual}\n      within_ms: .inf\n")
    with pytest.raises(ScenarioError, match=rf"{path}:11: expect.responses.0.within_ms: inf is greater than"):
        scenario.load(path)
