"""report.html of a synthetic run (the bus trace and a Zenoh capture that lost
one frame) shows the verdict and the lost frame (recording.mcap: test_recording.py)."""
from __future__ import annotations

import pytest
from synthetic import synthetic_run

from canbench import checks, report

pytestmark = pytest.mark.unit


@pytest.fixture
def result(tmp_path):
    r = synthetic_run(tmp_path)  # frame 50 lost on the way to Zenoh
    problems = checks.failing(r)
    r.metrics["verdicts"] = {f"test_check[{c}]": "failed" if c in problems else "passed" for c in checks.CHECKS}
    r.metrics["problems"], r.metrics["passed"] = problems, not problems
    return r


def test_html_shows_verdict_plots_and_lost_frame(result, tmp_path):
    report.write_html(result, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    assert "FAILED" in page and "can.log:51" in page
    assert page.count("data:image/png;base64,") == 2  # latency histogram + CDF, timeline
