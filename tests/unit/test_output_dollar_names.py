"""report.html of a run whose DBC has a value table of '$' names (a price level: $, $$, $$$) and a
unit with '$' in it: matplotlib reads text between two '$' as mathtext, so these names crashed
the whole report (ValueError while saving the signal plot; the run then exits 1 without a report)
or showed as mangled math. Every label the report draws from the DBC must be drawn as written."""
from __future__ import annotations

import pytest

from canbench import analysis, oracle, report, scenario, wire

pytestmark = pytest.mark.unit

DBC = """VERSION ""
NS_ :
BS_:
BU_: E
BO_ 192 Trip: 8 E
 SG_ Level : 0|8@1+ (1,0) [0|3] "" Vector__XXX
 SG_ Cost : 8|16@1+ (0.01,0) [0|655.35] "$" Vector__XXX
{values}
"""


def run(tmp_path, values='VAL_ 192 Level 0 "free" 1 "$" 2 "$$" 3 "$$$" ;'):
    (tmp_path / "car.dbc").write_text(DBC.format(values=values))
    (tmp_path / "t.log").write_text("(1700000000.000000) vcan0 0C0#0100000000000000\n")
    (tmp_path / "sc.yaml").write_text(
        "name: price\nduration_s: 10\ndbc: car.dbc\nbuses:\n  - name: vcan0\n"
        "ecus:\n  - name: e\n    bus: vcan0\n    trace: t.log\n"
        "expect:\n  signals:\n    Trip.Level: {one_of: [free, $]}\n"
        "    Trip.Cost: {range: [0, 100], max_rate: 5}\n")
    sc = scenario.load(tmp_path / "sc.yaml")
    with open(tmp_path / "can.log", "w") as bus, open(tmp_path / "zenoh.tsv", "w") as zen:
        for i in range(50):
            t = 1_700_000_000_000_000_000 + i * 10_000_000
            f = wire.Frame(0x0C0, 8, bytes([i % 4, i, 0, 0, 0, 0, 0, 0]))
            bus.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {f.candump('vcan0')}\n")
            zen.write(f"{t + 400_000}\tvehicle/can/rx\t{wire.encode(f).hex()}\t"
                      f"{wire.encode_attachment(i, [t]).hex()}\n")
    assert len(oracle.read_candump(tmp_path / "can.log", "vcan0")) == 50
    result = analysis.analyse(sc, "price", tmp_path, "vehicle/can", {}, None, 1.0)
    result.metrics["passed"] = False
    return result


def test_value_table_names_with_dollars_do_not_break_the_report(tmp_path):
    report.write_html(run(tmp_path), tmp_path / "report.html")  # ValueError: $$ (2) ... ParseException
    assert "<h2>Signals</h2>" in (tmp_path / "report.html").read_text()


def test_labels_from_the_dbc_are_drawn_as_written_not_as_math(tmp_path, monkeypatch):
    result = run(tmp_path, 'VAL_ 192 Level 0 "free" 1 "$" 2 "US$ 1 to US$ 9" 3 "x" ;')  # drawn "US1 to US9"
    texts = []

    def png(fig):
        texts.extend(t for ax in fig.axes for t in [ax.title, *ax.get_yticklabels()] if "$" in t.get_text())
        return "<img>"
    monkeypatch.setattr(report, "_png", png)
    report._signal_section(result)
    assert texts and all(not t._preprocess_math(t.get_text())[1] for t in texts)  # not mathtext
