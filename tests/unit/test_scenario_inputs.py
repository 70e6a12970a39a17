"""Scenario files as people write them: a key given twice, 1e3 for a number, a YAML error, an
id_remap the bus cannot carry. Each is one `file:line: key path: message` problem, never a
silent choice or a failure once the run started."""
from __future__ import annotations

import pytest

from canbench import validate

pytestmark = pytest.mark.unit

TRACE = "(1700000000.000000) vcan0 123#11\n(1700000000.010000) vcan0 12345678#22\n"


def problems(tmp_path, text: str) -> list[str]:
    (tmp_path / "trace.log").write_text(TRACE)
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return [str(p).removeprefix(f"{path}:") for p in validate.problems(path)]


BASE = "name: t\nduration_s: 5\nbuses: [{name: vcan0}]\n"
ECU = "ecus: [{name: e, bus: vcan0, trace: trace.log}]\n"


def test_a_key_given_twice_is_a_problem_not_the_last_one_silently(tmp_path):
    found = problems(tmp_path, BASE + ECU + "expect: {integrity: true}\nexpect: {ordering: true}\n")
    assert found == ["6: not valid YAML: duplicate key 'expect' (first at line 5)"]
    nested = problems(tmp_path, BASE + "ecus:\n  - name: e\n    bus: vcan0\n    trace: trace.log\n    name: f\n"
                                "expect: {integrity: true}\n")
    assert nested == ["8: not valid YAML: duplicate key 'name' (first at line 5)"]


def test_merge_keys_may_override(tmp_path):
    text = BASE + "x-ecu: &ecu {name: e, bus: vcan0, trace: trace.log}\n" \
                  "ecus: [{<<: *ecu, name: f}]\nexpect: {integrity: true}\n"
    assert all("duplicate" not in p for p in problems(tmp_path, text))


def test_exponent_without_a_dot_says_how_yaml_read_it(tmp_path):
    text = "name: t\nduration_s: 1e3\nbuses: [{name: vcan0}]\n" + ECU + "expect: {integrity: true}\n"
    found = problems(tmp_path, text)
    assert found == ["2: duration_s: '1e3' is not of type 'number' (YAML reads '1e3' as text: write 1.0e+3)"]


def test_a_yaml_error_is_one_line(tmp_path):
    found = problems(tmp_path, BASE + ECU + "expect: {integrity: true}\n\tbad: 1\n")
    assert found == ["6: not valid YAML: while scanning for the next token; found character '\\t' that cannot "
                     "start any token"]


def test_an_id_remap_beyond_the_bus_is_a_problem(tmp_path):
    ecus = ('ecus: [{name: e, bus: vcan0, trace: trace.log, id_remap: {"12345678": "FFFFFFFF"}},\n'
            '       {name: f, bus: vcan0, trace: trace.log, id_remap: {"123": "800", "12345678": "800"}}]\n')
    found = problems(tmp_path, BASE + ecus + "expect: {integrity: true}\n")
    assert found == ["4: ecus.0.id_remap.12345678: FFFFFFFF is above 1FFFFFFF, the largest CAN id",
                     "5: ecus.1.id_remap.123: the 11-bit frames of 123 (trace.log:1) would get id 800, above 7FF"]


def test_an_unquoted_id_key_is_a_problem_at_its_line_not_a_traceback(tmp_path):
    """An id written as a mapping key without quotes is a number to YAML (jsonschema's key patterns
    raised TypeError on it): said at its line, every one of them."""
    found = problems(tmp_path, BASE + "ecus: [{name: e, bus: vcan0, trace: trace.log,\n"
                                      "        id_remap: {316: '317'}}]\n"
                                      "expect:\n  cycle_time:\n    ids: {440: 10, 0x647: 20}\n")
    hint = "not text: quote it as written (an id such as 440 or 0x647 is a number to YAML unquoted: '440', '0x647')"
    assert found == [f"5: ecus.0.id_remap: YAML reads the key as the number 316, {hint}",
                     f"8: expect.cycle_time.ids: YAML reads the key as the number 440, {hint}",
                     f"8: expect.cycle_time.ids: YAML reads the key as the number 1607, {hint}"]
