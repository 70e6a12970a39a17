"""The signal parts of a run's outputs, on a run whose Zenoh side has one bit flipped inside
EngineSpeed (test_signals.flipped_run): report.html plots every gated signal with its limits and
the violation marked; recording.mcap carries the signals decoded on both sides with the bus's
DBC; metrics.json per-signal statistics."""
from __future__ import annotations

import json

import pytest
from mcap.reader import make_reader
from test_signals import DBC, flipped_run

from canbench import checks, recording, report, ros2_msgs

pytestmark = pytest.mark.unit


def test_report_plots_gated_signals_and_names_the_violation(tmp_path):
    result, _ = flipped_run(tmp_path)
    problems = checks.failing(result)
    result.metrics["verdicts"] = {f"test_check[{c}]": "failed" if c in problems else "passed" for c in checks.CHECKS}
    result.metrics["problems"], result.metrics["passed"] = problems, not problems
    report.write_html(result, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    assert "<h2>Signals</h2>" in page
    assert page.count("data:image/png;base64,") == 3  # latency, timeline, signals
    assert "EngineData.EngineSpeed = 9992 rpm outside [0, 8000]" in page  # in the verdicts
    # the table: each gated signal on each side, with its count and violations
    assert "<td>vcan0</td><td>EngineData.EngineSpeed</td><td>zenoh</td><td>200</td>" in page
    assert "<td>0</td><td>[0, 8000]</td>" in page and "<td>1</td><td>[0, 8000]</td>" in page
    metrics = json.loads((tmp_path / "metrics.json").read_text())["signals"]
    assert metrics["zenoh"]["vcan0"]["EngineData.EngineSpeed"]["max"] == 9992.0
    assert metrics["can"]["vcan0"]["EngineData.EngineSpeed"]["max"] == 2790.0


def test_the_plots_are_bounded_the_violated_first(tmp_path, monkeypatch):
    result, _ = flipped_run(tmp_path)
    monkeypatch.setattr(report, "SIGNAL_PLOTS", 1)
    seen = []
    monkeypatch.setattr(report, "_png", lambda fig: seen.append([a.get_title() for a in fig.axes]) or "<img>")
    section = report._signal_section(result)
    assert "3 more gated signals (the fewest violations) are not plotted" in section
    assert seen == [["vcan0 EngineData.EngineSpeed (rpm): [0, 8000]"]]


def test_the_report_of_a_run_without_signal_gates_has_no_signal_section(tmp_path):
    result, _ = flipped_run(tmp_path)
    object.__setattr__(result.scenario, "signal_gates", ())
    assert report._signal_section(result) == ""


def test_recording_decodes_both_sides_with_the_buses_dbc(tmp_path):
    result, flipped = flipped_run(tmp_path)
    assert result.scenario.bus_dbcs["vcan0"].name == DBC.name
    recording.write_mcap(result, tmp_path / "recording.mcap")  # no DBC given: the bus's own
    series: dict[str, list[float]] = {}
    with open(tmp_path / "recording.mcap", "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/EngineData/EngineSpeed"):
                series.setdefault(channel.topic, []).append(ros2_msgs.decode(schema.name, message.data).data)
    can, zen = series["/signals/vcan0/EngineData/EngineSpeed"], series["/signals_zenoh/vcan0/EngineData/EngineSpeed"]
    assert len(can) == len(zen) == 200
    differ = [i for i, (a, b) in enumerate(zip(can, zen, strict=True)) if a != b]
    assert len(differ) == 1 and zen[differ[0]] - can[differ[0]] == 8192
