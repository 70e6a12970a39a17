"""Authoring help and the nightly gate on hand-made inputs: trace summary,
scaffolded scenarios that validate, and `canbench compare` catching each kind
of regression while ignoring noise."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from canbench import authoring, cli, scenario, tracegen
from canbench.trace import read_trace

pytestmark = pytest.mark.unit


def test_summary_infers_cycle_times_and_load(tmp_path):
    trace = tmp_path / "t.log"
    tracegen.write(trace, tracegen.generate(2.0))
    s = authoring.summarise(trace, 500_000)
    cycles = {i.ident: i.cycle_ms for i in s.ids}
    assert cycles["0C0"] == pytest.approx(10.0) and cycles["18FEF100"] == pytest.approx(100.0)
    assert 4 < s.load_pct < 7  # ~190 frames/s of ~8 bytes at 500 kbit/s


def test_summary_spans_a_log_whose_second_interface_starts_earlier(tmp_path):
    """candump of several interfaces is in time order per interface only: the span is from the
    earliest frame to the latest, not from the first line to the last (it was -0.5 s here)."""
    trace = tmp_path / "two.log"
    trace.write_text("(1700000000.500000) can0 123#11\n(1700000000.000000) can1 456#22\n"
                     "(1700000001.000000) can1 456#22\n(1700000000.600000) can0 123#11\n")
    s = authoring.summarise(trace, 500_000)
    assert s.frames == 4 and s.span_s == pytest.approx(1.0)


def test_scaffold_copies_the_trace_and_validates(tmp_path):
    trace = tmp_path / "recorded" / "drive.log"
    tracegen.write(trace, tracegen.generate(1.0))
    out = tmp_path / "scenarios" / "drive.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "drive", "--out", str(out)]) == 0
    sc = scenario.load(out)
    assert sc.ecus[0].trace == (tmp_path / "scenarios" / "traces" / "drive.log").resolve()
    assert sc.expect["cycle_time"]["ids"]["0C0"] == pytest.approx(10.0)
    assert cli.main(["scaffold", str(trace), "--name", "drive", "--out", str(out)]) == 2  # no silent overwrite


def test_scaffold_gives_each_interface_its_bus_and_gates_only_steady_cycles(tmp_path, capsys):
    # id 100 every 10 ms on each of two interfaces, 1 ms apart: merged, its gaps would be 1, 9, 1, 9 ms
    # (median 1 ms); each interface is a bus of its own, where it is periodic; id 200 every 20 ms on
    # can0 is periodic; id 300 every 10 ms on can0 and every 30 ms on can1: one gate cannot hold both
    trace = tmp_path / "two.log"
    lines = []
    for i in range(100):
        t = 1_700_000_000 + i * 0.01
        lines += [f"({t:.6f}) can0 100#{i:02X}", f"({t + 0.001:.6f}) can1 100#{i:02X}",
                  f"({t + 0.002:.6f}) can0 300#00"]
        if i % 2 == 0:
            lines.append(f"({t + 0.005:.6f}) can0 200#00")
        if i % 3 == 0:
            lines.append(f"({t + 0.006:.6f}) can1 300#00")
    trace.write_text("\n".join(lines) + "\n")
    out = tmp_path / "two.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "two", "--out", str(out)]) == 0
    sc = scenario.load(out)
    assert sc.bus_names == ["vcan0", "vcan1"] and [(e.name, e.bus) for e in sc.ecus] == [
        ("recorded-vcan0", "vcan0"), ("recorded-vcan1", "vcan1")]
    assert [len(read_trace(e.trace)) for e in sc.ecus] == [250, 134]
    assert [e.start_offset_s for e in sc.ecus] == [0.0, 0.001]  # can1's first frame 1 ms after the trace's
    assert {str(m.channel) for m in (tf.message for tf in read_trace(sc.ecus[1].trace))} == {"vcan1"}
    assert sc.expect["cycle_time"]["ids"] == {"100": pytest.approx(10.0), "200": pytest.approx(20.0)}
    said = capsys.readouterr().out
    assert "The trace's interfaces can0 -> vcan0, can1 -> vcan1: one bus and one replay ECU each" in said
    assert "Not gated in cycle_time.ids: 300 (periodic on one interface" in said
    assert "can0 -> vcan0, can1 -> vcan1" in out.read_text()


def metrics(p50=0.5, lost=0, verdict="passed") -> dict:
    summary = {"sent": 100, "matched": 100 - lost, "lost": lost, "duplicates": 0, "corrupted": 0, "reordered": 0,
               "latency": {"count": 100, "p50_ms": p50, "p90_ms": p50 * 2, "p99_ms": p50 * 3, "max_ms": p50 * 4}}
    return {"schema_version": 1, "run_id": "r", "scenario": "smoke", "can_to_zenoh": {"vcan0": summary},
            "verdicts": {"test_check[integrity]": verdict}}


@pytest.mark.parametrize("new,regressed", [
    (metrics(), False),
    (metrics(p50=0.52), False),              # noise
    (metrics(p50=0.09 / 0.5 * 0.5), False),  # faster
    (metrics(p50=1.0), True),                # +100%
    (metrics(lost=1), True),
    (metrics(verdict="failed"), True),
])
def test_compare_exit_code(tmp_path, capsys, new, regressed):
    old_path, new_path = tmp_path / "old.json", tmp_path / "new.json"
    old_path.write_text(json.dumps(metrics()))
    new_path.write_text(json.dumps(new))
    assert cli.main(["compare", str(old_path), str(new_path)]) == (1 if regressed else 0)
    assert ("REGRESSION" in capsys.readouterr().out) == regressed


def test_compare_from_a_baseline_of_zero_says_by_how_much_not_a_percentage(tmp_path, capsys):
    (tmp_path / "a.json").write_text(json.dumps(metrics(p50=0.0)))
    (tmp_path / "b.json").write_text(json.dumps(metrics(p50=5.0)))
    assert cli.main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 1
    row = next(line for line in capsys.readouterr().out.splitlines() if "p50_ms" in line)
    assert "+5.000 ms from 0.000" in row and "+0%" not in row


def test_compare_of_a_run_whose_checks_never_ran_is_a_regression(tmp_path, capsys):
    stopped = metrics()
    stopped["verdicts"] = {}  # metrics written, the checks' session killed before it added them
    (tmp_path / "a.json").write_text(json.dumps(metrics()))
    (tmp_path / "b.json").write_text(json.dumps(stopped))
    assert cli.main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 1
    assert "no check ran" in capsys.readouterr().out


def test_compare_refuses_a_file_that_is_not_a_metrics_object(tmp_path, capsys):
    (tmp_path / "a.json").write_text(json.dumps(metrics()))
    (tmp_path / "b.json").write_text("[]")
    assert cli.main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 2
    assert "not a run's metrics.json: a JSON list, not an object" in capsys.readouterr().err


def test_compare_refuses_unknown_schema(tmp_path):
    bad = copy.deepcopy(metrics())
    bad["schema_version"] = 99
    (tmp_path / "a.json").write_text(json.dumps(metrics()))
    (tmp_path / "b.json").write_text(json.dumps(bad))
    assert cli.main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) == 2
    assert Path(tmp_path / "b.json").exists()
