"""The signal databases cantools reads beside DBC, by their suffix: KCD (as here), SYM and ARXML
serve a scenario's `dbc:` as a DBC does (gates, cycle times); a CDD, which cantools reads as a
diagnostics database (services, not CAN messages), is refused at its line with what to give."""
from __future__ import annotations

from pathlib import Path

import pytest
from synthetic import signal_problems

from canbench import dbc, scenario, wire
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

KCD = """<NetworkDefinition xmlns="http://kayak.2codeornot2code.org/1.0">
  <Node id="1" name="Node1"/>
  <Bus name="Bus1">
    <Message id="0x101" name="Message1" interval="50">
      <Producer><NodeRef id="1"/></Producer>
      <Signal name="Signal1" offset="0" length="8"><Value intercept="-10"/></Signal>
      <Signal name="Signal2" offset="8" length="8"/>
    </Message>
  </Bus>
</NetworkDefinition>
"""
CDD = '<?xml version="1.0"?>\n<CANDELA><ECUDOC><ECU><VAR></VAR></ECU></ECUDOC></CANDELA>\n'


def scenario_with(tmp: Path, database: str, expect: str) -> Path:
    (tmp / "trace.log").write_text("(1700000000.000000) vcan0 101#0000\n")
    path = tmp / "sc.yaml"
    path.write_text(f"name: formats\nduration_s: 10\ndbc: {database}\nbuses:\n  - name: vcan0\n"
                    "ecus:\n  - name: e\n    bus: vcan0\n    trace: trace.log\nexpect:\n" + expect)
    return path


def test_a_kcd_serves_as_a_dbc(tmp_path):
    (tmp_path / "car.kcd").write_text(KCD)
    path = scenario_with(tmp_path, "car.kcd", "  signals:\n    Message1.Signal1: {range: [0, 100]}\n")
    assert signal_problems(path, [wire.Frame(0x101, 2, bytes([20, 0]))]) == []  # 20 - 10
    problems = signal_problems(path, [wire.Frame(0x101, 2, bytes([5, 0]))])
    assert len(problems) == 1 and "Message1.Signal1 = -5 outside [0, 100]" in problems[0]
    [message] = dbc.load_dbc(tmp_path / "car.kcd").messages
    assert dbc.cycle_time_ms(message) == 50


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # cantools' own, on reading a CDD
def test_a_diagnostics_database_is_refused_with_what_to_give(tmp_path):
    (tmp_path / "ecu.cdd").write_text(CDD)
    path = scenario_with(tmp_path, "ecu.cdd", "  integrity: true\n")
    with pytest.raises(ScenarioError, match=r"sc.yaml:3: dbc: cannot use ecu.cdd as a DBC: a diagnostics database "
                                            r"\(services and identifiers\), not CAN messages: give a DBC"):
        scenario.load(path)
