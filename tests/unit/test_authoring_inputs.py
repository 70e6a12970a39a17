"""summarise and scaffold on recordings as they come from a car: several interfaces in one log,
a day-long gap, a million frames; what they print and write is right or refused, and a
scenario that would not validate is never left behind."""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from canbench import authoring, cli
from canbench.trace import format_line
from canbench.wire import Frame

pytestmark = pytest.mark.unit


def two_buses(tmp_path):
    """id 100 every 10 ms on can0 and on can1, 1 ms apart (merged: gaps of 1 and 9 ms)."""
    trace = tmp_path / "two.log"
    trace.write_text("".join(f"({1_700_000_000 + i * 0.01:.6f}) can0 100#{i:02X}\n"
                             f"({1_700_000_000 + i * 0.01 + 0.001:.6f}) can1 100#{i:02X}\n" for i in range(50)))
    return trace


def test_summary_is_per_interface_each_a_bus_of_its_own(tmp_path):
    s = authoring.summarise(two_buses(tmp_path), 500_000)
    assert [(i.interface, i.ident, i.count, i.cycle_ms) for i in s.ids] == [
        ("can0", "100", 50, pytest.approx(10.0)), ("can1", "100", 50, pytest.approx(10.0))]
    assert set(s.loads) == {"can0", "can1"} and s.loads["can0"] == pytest.approx(s.loads["can1"])
    assert "bus load can0 " in s.table() and s.table().splitlines()[1].split()[0] == "interface"


def test_summary_names_the_longest_gap(tmp_path):
    trace = tmp_path / "gap.log"
    trace.write_text("(1700000000.000000) can0 123#11\n(1700000000.010000) can0 123#11\n"
                     "(1700003600.010000) can0 123#11\n")
    s = authoring.summarise(trace)
    assert (s.longest_gap_s, s.longest_gap_line) == (pytest.approx(3600.0), 3)
    assert "longest gap 3600.000 s (before line 3)" in s.table()


def test_a_trace_longer_than_a_scenario_can_run_is_refused_before_anything_is_written(tmp_path, capsys):
    trace = tmp_path / "day.log"
    trace.write_text("(1700000000.000000) can0 123#11\n(1700000000.010000) can0 123#11\n"
                     "(1700086400.010000) can0 123#11\n")
    out = tmp_path / "sc" / "day.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "day", "--out", str(out)]) == 2
    assert capsys.readouterr().err == (f"canbench: {trace}: spans 86400 s (its longest gap 86400 s, before line 3): "
                                       "a scenario runs at most 86400 s; cut the trace\n")
    assert not out.exists() and not (out.parent / "traces").exists()


def test_a_scaffold_that_does_not_validate_is_not_left_behind(tmp_path, monkeypatch, capsys):
    trace = two_buses(tmp_path)
    monkeypatch.setattr(authoring, "scaffold", lambda *args: "name: x\nduration_s: -1\n")
    out = tmp_path / "x.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "x", "--out", str(out)]) == 2
    assert f"canbench: {out}: not written: the scaffold does not validate: " in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [trace]


def test_summarise_keeps_no_frames(tmp_path):
    # 50 000 frames held as python-can messages would be ~40 MiB; one pass keeps per id its gaps
    trace = tmp_path / "big.log"
    with open(trace, "w") as out:
        for n in range(50_000):
            out.write(format_line(1_700_000_000_000_000_000 + n * 500_000, "can0",
                                  Frame(0x100 + n % 16, 8, n.to_bytes(8, "little"))) + "\n")
    tracemalloc.start()
    try:
        s = authoring.summarise(trace)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert s.frames == 50_000 and s.ids[0].cycle_ms == pytest.approx(8.0, abs=1e-3)
    assert peak < 8 * 2**20, f"{peak / 2**20:.1f} MiB"


def test_signal_statistics_say_they_are_over_every_interface(tmp_path):
    trace = tmp_path / "two.log"  # MM5_10_TX1 (0x070) of cantools' abs.dbc on can0 and can1
    trace.write_text("(1700000000.000000) can0 070#0000000000000000\n(1700000000.000500) can1 070#0000000000000000\n")
    dbc = Path(__file__).resolve().parents[1] / "data" / "dbc" / "cantools" / "abs.dbc"
    table = authoring.summarise_signals(trace, dbc).table()
    assert table.startswith(f"{trace}: signals decoded with {dbc} (cantools) (over can0, can1 together): 1 messages")
    assert "MM5_10_TX1 (070): 2 frames" in table


GOOD = "(1700000000.000000) can0 123#11\n(1700000000.010000) can0 123#22\n"


@pytest.mark.parametrize("dbc_text,said", [
    ("garbage\n", "cannot load it as a DBC (cantools): {dbc}:1: DBC: \"Invalid syntax at line 1, column 1: "
                   "\">>!<<garbage\"\""),
    (None, "no such DBC file"),
])
@pytest.mark.parametrize("command", ["summarise", "scaffold"])
def test_a_dbc_cantools_cannot_read_is_one_line_and_exit_code_2(tmp_path, capsys, dbc_text, said, command):
    trace, dbc = tmp_path / "t.log", tmp_path / "car.dbc"
    trace.write_text(GOOD)
    if dbc_text is not None:
        dbc.write_text(dbc_text)
    extra = ["--name", "x", "--out", str(tmp_path / "sc" / "x.yaml")] if command == "scaffold" else []
    assert cli.main([command, str(trace), "--dbc", str(dbc), *extra]) == 2
    assert capsys.readouterr().err == f"canbench: {dbc}: {said.format(dbc=dbc)}\n"
    assert not (tmp_path / "sc" / "x.yaml").exists()


@pytest.mark.parametrize("command", ["summarise", "scaffold"])
def test_a_bitrate_of_zero_is_refused_by_the_command_line(tmp_path, command):
    trace = tmp_path / "t.log"
    trace.write_text(GOOD)
    extra = ["--name", "x", "--out", str(tmp_path / "x.yaml")] if command == "scaffold" else []
    with pytest.raises(SystemExit) as exit_:
        cli.main([command, str(trace), "--bitrate", "0", *extra])
    assert exit_.value.code == 2


def test_scaffold_does_not_write_over_its_trace_or_take_a_bad_name(tmp_path, capsys):
    trace = tmp_path / "t.log"
    trace.write_text(GOOD)
    assert cli.main(["scaffold", str(trace), "--name", "x", "--out", str(trace), "--force"]) == 2
    said = f"canbench: {trace}: is the trace itself: --out names the scenario file to write\n"
    assert capsys.readouterr().err == said
    assert trace.read_text() == GOOD
    assert cli.main(["scaffold", str(trace), "--name", "My Drive", "--out", str(tmp_path / "sc" / "x.yaml")]) == 2
    assert "--name: 'My Drive': a scenario's name is lowercase letters, digits, - and _" in capsys.readouterr().err
    assert not (tmp_path / "sc").exists()


def test_a_burst_at_one_stamp_names_no_gap(tmp_path):
    trace = tmp_path / "burst.log"
    trace.write_text("(1700000000.000000) can0 123#11\n(1700000000.000000) can0 124#11\n")
    assert authoring.summarise(trace).table().splitlines()[0].endswith("(worst-case stuffing)")
