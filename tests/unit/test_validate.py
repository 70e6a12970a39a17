"""`canbench validate` reports every problem at once, file:line each, with the paths as the
user gave them (issue: it stopped at the first, and bench-run did not read the traces)."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import cli, validate

pytestmark = pytest.mark.unit

TRACE = ("(1700000000.000000) vcan0 123#DEADBEEF\n"
         "(1700000000.001000) vcan0 16G#D032\n"            # not hex
         "(1700000000.002000) vcan0 124#00\n"
         "(1700000000.003000) vcan0 125#000102030405060708\n"  # 9 data bytes
         "(1699999999.000000) vcan0 126#00\n")             # goes back in time

SCENARIO = """name: two-problems
duration_s: ten
buses:
  - name: vcan0
ecus:
  - name: engine
    bus: vcan9
    trace: traces/t.log
  - name: tester
    bus: vcan0
    role: echo
expect:
  integrity: true
  colour: blue
"""


@pytest.fixture
def bad(tmp_path, monkeypatch) -> Path:
    (tmp_path / "sc" / "traces").mkdir(parents=True)
    (tmp_path / "sc" / "traces" / "t.log").write_text(TRACE)
    (tmp_path / "sc" / "s.yaml").write_text(SCENARIO)
    monkeypatch.chdir(tmp_path)
    return Path("sc/s.yaml")


def test_every_problem_with_file_line_as_the_user_wrote_it(bad, capsys):
    assert cli.main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[:-1] == [
        "sc/s.yaml:2: duration_s: 'ten' is not of type 'number'",
        "sc/s.yaml:7: ecus.0.bus: 'vcan9' is not one of the buses ['vcan0']",
        "sc/s.yaml:9: ecus.1: role echo needs echo_ids",
        "sc/s.yaml:14: expect: Additional properties are not allowed ('colour' was unexpected)",
        "sc/traces/t.log:2: not a candump -L frame: '(1700000000.001000) vcan0 16G#D032'",
        "sc/traces/t.log:4: 9 data bytes: classic CAN carries at most 8",
        "sc/traces/t.log:5: timestamp earlier than the line before (1699999999.000000 s after 1700000000.002000 s)",
    ], err
    assert err[-1] == "canbench validate: 7 problems in 1 of 1 scenario file"


def test_good_files_pass_and_bad_ones_are_all_named(bad, tmp_path, capsys):
    good = tmp_path / "sc" / "good.yaml"
    good.write_text("name: g\nduration_s: 5\nbuses: [{name: vcan0}]\n"
                    "ecus: [{name: e, bus: vcan0, role: echo, echo_ids: ['600']}]\nexpect: {integrity: true}\n")
    assert validate.run([good, bad, Path("sc/missing.yaml")]) == 2
    out, err = capsys.readouterr()
    assert f"{good}: ok (1 ECUs on vcan0)" in out
    assert "sc/missing.yaml: cannot read: No such file or directory" in err
    assert err.splitlines()[-1] == "canbench validate: 8 problems in 2 of 3 scenario files"


def test_a_trace_in_another_format_is_cut_short(tmp_path):
    trace = tmp_path / "t.log"
    trace.write_text("".join(f"{i} 0x123 8 00 00 00 00 00 00 00 00\n" for i in range(100)) +
                     "(1700000000.000000) vcan0 123#00\n")
    found = validate.trace_problems(trace)
    # a trace's line that is not a frame, blank or a comment is a problem (canplayer would skip it,
    # and the file would be read as candump with one frame)
    assert str(found[0]) == f"{trace}:1: not a candump -L frame: '0 0x123 8 00 00 00 00 00 00 00 00'"
    assert len(found) == validate.MAX_PER_TRACE + 1
    trace.write_text("".join(f"(1700000000.{i:06d}) vcan0 12#00\n" for i in range(100)))
    found = validate.trace_problems(trace)
    assert len(found) == validate.MAX_PER_TRACE + 1
    assert str(found[-1]) == f"{trace}: {100 - validate.MAX_PER_TRACE} more problems like the ones above"


def test_shipped_scenarios_validate_from_the_repository(capsys, monkeypatch):
    repo = Path(__file__).resolve().parents[2]
    monkeypatch.chdir(repo)
    paths = sorted(Path("scenarios").glob("**/*.yaml"))
    assert paths and validate.run(paths) == 0
    assert capsys.readouterr().err == ""
