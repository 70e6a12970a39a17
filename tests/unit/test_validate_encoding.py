"""canbench validate makes what the DBC encodes (restbus ECUs, commands in signals) as the run
would: a frame cantools cannot encode is a problem at the entry's line, exit code 2, not a
traceback in the ECU's container once the run started."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from canbench import validate

pytestmark = pytest.mark.unit

ABS = Path(__file__).resolve().parents[1] / "data" / "dbc" / "cantools" / "abs.dbc"


def test_a_restbus_node_with_a_multiplexed_message_it_cannot_encode_is_a_problem(tmp_path, capsys):
    # cantools' abs.dbc: ABS sends BREMSE_52, multiplexed by Mplx_SW_Info over 1..7; its start value is 0
    shutil.copyfile(ABS, tmp_path / "abs.dbc")
    path = tmp_path / "abs.yaml"
    path.write_text("name: abs\nduration_s: 10\ndbc: abs.dbc\nbuses: [{name: vcan0}]\n"
                    "ecus:\n  - name: abs\n    bus: vcan0\n    role: restbus\n    dbc_node: ABS\n    run_s: 2\n"
                    "expect: {integrity: true}\n")
    assert validate.run([path]) == 2
    assert capsys.readouterr().err.splitlines()[0] == (
        f"{path}:6: ecus.0: a frame cannot be encoded with the DBC: Expected multiplexer id in {{1, 2, 3, 4, 5, 6 "
        "or 7}, for multiplexer \"Mplx_SW_Info\" but got 0")


def test_commands_in_signals_at_a_valid_multiplexer_value_pass(tmp_path):
    shutil.copyfile(ABS, tmp_path / "abs.dbc")
    path = tmp_path / "cmd.yaml"
    path.write_text("name: cmd\nduration_s: 10\ndbc: abs.dbc\nbuses: [{name: vcan0}]\n"
                    "ecus: [{name: e, bus: vcan0, role: echo, echo_ids: ['600']}]\n"
                    "commands: [{bus: vcan0, message: BREMSE_52, signals: {Mplx_SW_Info: 2, BB_dig1: 4}, run_s: 1}]\n"
                    "expect: {integrity: true}\n")
    assert validate.problems(path) == []
