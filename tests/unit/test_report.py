"""Report writers on a synthetic run (the bus trace and a Zenoh capture that
lost one frame): the MCAP recording reads back with the documented channels
and decoded signals; the HTML page shows the verdict and the lost frame."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from synthetic import synthetic_run

from canbench import checks, dbc, report

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def result(tmp_path):
    r = synthetic_run(tmp_path)  # frame 50 lost on the way to Zenoh
    problems = checks.failing(r)
    r.metrics["verdicts"] = {f"test_check[{c}]": "failed" if c in problems else "passed" for c in checks.CHECKS}
    r.metrics["problems"], r.metrics["passed"] = problems, not problems
    return r


def test_mcap_has_documented_channels_and_signals(result, tmp_path):
    report.write_mcap(result, tmp_path / "recording.mcap", dbc.load_dbc(result.scenario.dbc))
    with open(tmp_path / "recording.mcap", "rb") as f:
        reader = make_reader(f)
        counts: dict[str, int] = {}
        speeds = []
        for _, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/signals/vcan0/EngineData":
                speeds.append(json.loads(message.data)["EngineSpeed"])
    assert counts["/can/vcan0"] == 388 and counts["/zenoh/vcan0"] == 387
    assert counts["/signals/vcan0/EngineData"] == 200 and len(set(speeds)) > 10


def test_html_shows_verdict_plots_and_lost_frame(result, tmp_path):
    report.write_html(result, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    assert "FAILED" in page and "can.log:51" in page
    assert page.count("data:image/png;base64,") == 2  # latency histogram + CDF, timeline
