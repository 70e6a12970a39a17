"""What a failing run writes for CI and engineers stays bounded however many frames failed: the
problems in metrics.json, junit.xml and report.html list SHOW examples and count the rest (a
bridge that sends 5000 malformed samples, publishes on 300 stray keys, or misses 400 responses
wrote one line for each), the per-id table is cut, and the timeline's bins do not grow with the
run's length (24 h: 864 001 bins of 100 ms, minutes of plotting)."""
from __future__ import annotations

import matplotlib.axes
import pytest
from synthetic import REPO, synthetic_run

from canbench import analysis, checks, report, scenario, wire

pytestmark = pytest.mark.unit
T0 = 1_700_000_000_000_000_000


def test_malformed_samples_and_stray_keys_are_listed_bounded(tmp_path):
    synthetic_run(tmp_path, lose=None)
    with open(tmp_path / "zenoh.tsv", "a") as f:
        f.writelines(f"{T0 + i}\tvehicle/can/rx\tff\t-\n" for i in range(5000))  # undecodable
        f.writelines(f"{T0 + i}\tvehicle/can/stray/{i}\t00\t-\n" for i in range(300))
    r = analysis.analyse(scenario.load(REPO / "scenarios" / "smoke.yaml"), "x", tmp_path, "vehicle/can", {}, None, 2)
    problems = checks.failing(r)
    assert "5000" in " ".join(problems["integrity"])  # counted
    assert len(problems["integrity"]) <= checks.SHOW + 1  # was 5000 lines
    assert "300" in problems["only_expected_keys"][0] and len(problems["only_expected_keys"][0]) < 2000  # was 7 kB


def test_per_id_table_is_bounded(tmp_path):
    with open(tmp_path / "can.log", "w") as bus, open(tmp_path / "zenoh.tsv", "w") as zen:
        for i in range(6000):  # 3000 distinct 29-bit ids, two frames each
            t, f = T0 + i * 1_000_000, wire.Frame(0x100000 + i % 3000, 1, b"\x00", extended=True)
            bus.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
            zen.write(f"{t + 400_000}\tvehicle/can/rx\t{wire.encode(f).hex()}\t"
                      f"{wire.encode_attachment(i, [t]).hex()}\n")
    r = analysis.analyse(scenario.load(REPO / "scenarios" / "smoke.yaml"), "x", tmp_path, "vehicle/can", {}, None, 6)
    r.metrics["passed"] = True
    report.write_html(r, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    rows = page[page.index("<h2>Per id</h2>"):].split("</table>")[0].count("<tr>")
    assert rows <= 1001  # was 3001 (one per id: 120 bytes each, unbounded)


def test_timeline_bins_do_not_grow_with_the_run(tmp_path, monkeypatch):
    day = 86_400 * 10**9
    with open(tmp_path / "can.log", "w") as bus, open(tmp_path / "zenoh.tsv", "w") as zen:
        for i, t in enumerate([T0, T0 + day]):  # a 24 h soak's first and last frame
            f = wire.Frame(0x0C0, 1, b"\x00")
            bus.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
            zen.write(f"{t + 400_000}\tvehicle/can/rx\t{wire.encode(f).hex()}\t"
                      f"{wire.encode_attachment(i, [t]).hex()}\n")
    r = analysis.analyse(scenario.load(REPO / "scenarios" / "smoke.yaml"), "x", tmp_path, "vehicle/can", {}, None, 1)
    seen, hist = [], matplotlib.axes.Axes.hist

    def counted(ax, x, bins=10, **kw):  # the bins asked for, drawn with 3 (the test stays fast)
        seen.append(bins if isinstance(bins, int) else len(bins) - 1)
        return hist(ax, x, bins=3, **kw)
    monkeypatch.setattr(matplotlib.axes.Axes, "hist", counted)
    report._timeline(r)
    assert seen and max(seen) <= 5000  # was 864 001


def test_missed_responses_are_listed_bounded(tmp_path):
    (tmp_path / "t.log").write_text("(1700000000.000000) vcan0 320#0000000000000000\n")
    (tmp_path / "sc.yaml").write_text(
        f"name: doors\nduration_s: 10\ndbc: {REPO}/scenarios/dbc/powertrain.dbc\nbuses:\n  - name: vcan0\n"
        "ecus:\n  - name: e\n    bus: vcan0\n    trace: t.log\nexpect:\n  responses:\n    - name: unlock\n"
        "      when: {signal: BodyStatus.DoorsLocked, equals: 1}\n"
        "      then: {signal: TorqueResponse.TorqueActual, range: [-1000, 1000], side: can}\n      within_ms: 5\n")
    with open(tmp_path / "can.log", "w") as bus:
        for i in range(800):  # the doors locked 400 times, never answered
            t, f = T0 + i * 10_000_000, wire.Frame(0x320, 8, bytes([(i % 2) << 4, 0, 0, 0, 0, 0, 0, 0]))
            bus.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
    (tmp_path / "zenoh.tsv").write_text("")
    r = analysis.analyse(scenario.load(tmp_path / "sc.yaml"), "x", tmp_path, "vehicle/can", {}, None, 8)
    assert r.metrics["responses"]["unlock"]["missing"] == 400
    assert len(checks.responses(r)) <= checks.SHOW + 2  # was 400 lines, in metrics.json twice
