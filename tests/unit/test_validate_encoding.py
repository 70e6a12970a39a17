"""canbench validate makes what the DBC encodes (restbus ECUs, commands in signals) as the run
would: a frame cantools cannot encode is a problem at the entry's line, exit code 2, not a
traceback in the ECU's container once the run started."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from cantools.database.errors import EncodeError

from canbench import dbc, plans, restbus, scenario, validate

pytestmark = pytest.mark.unit

ABS = Path(__file__).resolve().parents[1] / "data" / "dbc" / "cantools" / "abs.dbc"


def abs_restbus(tmp_path: Path) -> Path:
    shutil.copyfile(ABS, tmp_path / "abs.dbc")
    path = tmp_path / "abs.yaml"
    path.write_text("name: abs\nduration_s: 10\ndbc: abs.dbc\nbuses: [{name: vcan0}]\n"
                    "ecus:\n  - name: abs\n    bus: vcan0\n    role: restbus\n    dbc_node: ABS\n    run_s: 2\n"
                    "expect: {integrity: true}\n")
    return path


def test_a_restbus_node_with_a_multiplexed_message_sends_its_pages_in_turn(tmp_path, capsys):
    # cantools' abs.dbc: ABS sends BREMSE_52, multiplexed by Mplx_SW_Info over 1..7; its start value is 0
    # (which no page has: the plan raised EncodeError, then validate said so, before pages were sent in turn)
    path = abs_restbus(tmp_path)
    assert validate.run([path]) == 0
    sc = scenario.load(path)
    m = dbc.load_dbc(tmp_path / "abs.dbc").get_message_by_name("BREMSE_52")
    muxes = [m.decode(f.data)["Mplx_SW_Info"] for _, f in plans.schedule(sc.ecus[0], sc).frames()
             if f.arbitration_id == m.frame_id]
    assert muxes[:8] == [1, 2, 3, 4, 5, 6, 7, 1]


def test_a_frame_cantools_cannot_encode_is_a_problem_at_the_entry(tmp_path, capsys, monkeypatch):
    # what is left for this net once the values are checked: any EncodeError of a plan
    def refuse(self, values, n):
        raise EncodeError("Expected multiplexer id in {1 or 2}, for multiplexer \"X\" but got 0")
    monkeypatch.setattr(restbus.MessagePlan, "encode", refuse)
    path = abs_restbus(tmp_path)
    assert validate.run([path]) == 2
    assert capsys.readouterr().err.splitlines()[0] == (
        f"{path}:6: ecus.0: a frame cannot be encoded with the DBC: BREMSE_33: Expected multiplexer id in {{1 or 2}}, "
        "for multiplexer \"X\" but got 0")


def test_commands_in_signals_at_a_valid_multiplexer_value_pass(tmp_path):
    shutil.copyfile(ABS, tmp_path / "abs.dbc")
    path = tmp_path / "cmd.yaml"
    path.write_text("name: cmd\nduration_s: 10\ndbc: abs.dbc\nbuses: [{name: vcan0}]\n"
                    "ecus: [{name: e, bus: vcan0, role: echo, echo_ids: ['600']}]\n"
                    "commands: [{bus: vcan0, message: BREMSE_52, signals: {Mplx_SW_Info: 2, BB_dig1: 4}, run_s: 1}]\n"
                    "expect: {integrity: true}\n")
    assert validate.problems(path) == []
