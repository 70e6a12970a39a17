"""cycle_time.ids names each id as candump writes it: '123' is the 11-bit id, '00000123' the 29-bit
one, and a bus carrying both at different cycles has each gated against its own; two keys of one
id ('123' and '0123') are a problem at the second's line, not a silent override."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from canbench import checks, scenario, wire
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit


def cycles(p50_ms: float) -> dict:
    side = {"count": 50, "cycle_p50_ms": p50_ms, "cycle_min_ms": p50_ms, "cycle_max_ms": p50_ms}
    return {"can": side, "zenoh": dict(side)}


def result(ids: dict) -> SimpleNamespace:
    """A run whose bus and Zenoh both carry 11-bit 123 every 10 ms and 29-bit 00000123 every 100 ms."""
    bus = SimpleNamespace(bus="vcan0", cycle_times={"123": cycles(10.0), "00000123": cycles(100.0)})
    return SimpleNamespace(scenario=SimpleNamespace(expect={"cycle_time": {"tolerance_pct": 20, "ids": ids}}),
                           buses=[bus])


def test_an_11_bit_and_a_29_bit_id_of_one_number_are_gated_apart():
    # as scaffold writes them for such a trace: each passes against its own cycle
    assert checks.cycle_time(result({"123": 10.0, "00000123": 100.0})) == []
    assert checks.cycle_time(result({"00000123": 10.0})) == [
        "vcan0 id 00000123: median cycle 100.00 ms on Zenoh, expected 10.00 ms +-20%"]


@pytest.mark.parametrize("text,key", [("123", "123"), ("0123", "123"), ("7FF", "7FF"), ("800", "00000800"),
                                      ("18FEF100", "18FEF100"), ("00000123", "00000123")])
def test_a_key_is_29_bit_when_written_with_8_digits_or_above_7ff(text, key):
    assert wire.id_key(text) == key


def test_two_keys_of_one_id_are_a_problem_at_the_second(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("name: t\nduration_s: 5\nbuses: [{name: vcan0}]\n"
                    "ecus: [{name: g, bus: vcan0, role: periodic, run_s: 1, messages: [{id: '123', cycle_ms: 10}]}]\n"
                    "expect:\n  cycle_time:\n"
                    "    tolerance_pct: 20\n    ids:\n      '123': 10\n      '0123': 50\n      '00000123': 100\n")
    with pytest.raises(ScenarioError) as err:
        scenario.load(path)
    assert str(err.value) == (f"{path}:10: expect.cycle_time.ids.0123: the same id as 123 (123): an 11-bit id is "
                              "at most 7FF, a 29-bit one is written with 8 digits (00000123)")
