"""bench/qos.py's arithmetic on hand-made measurements: the ratios side by side (latency without
the QoS table over with it, loss of each QoS against reliable + block) and the report's rows."""
from __future__ import annotations

import pytest

from bench import qos

pytestmark = pytest.mark.unit


def prio(variant, p50, p99, table=""):
    return {"variant": variant, "table": table, "p50_us": p50, "p90_us": p50, "p99_us": p99, "max_us": p99,
            "lost": 0, "flood": {"offered_fps": 1, "sent": 1, "received": 1, "delivered_fps": 1}}


def loss(variant, lost):
    return {"variant": variant, "table": "", "lost": lost, "sent": 1000, "loss_pct": lost / 10, "pause_s": 1.5,
            "p50_us": 1.0, "max_us": 2.0}


def test_ratios_put_without_the_table_over_with_it_and_each_loss_over_reliable_block():
    rows = [prio("alone", 100, 200), prio("flood, no table", 5000, 90000), prio("flood, table", 250, 900, "t")]
    lost = [loss("reliable, block", 0), loss("best-effort, drop", 300), loss("reliable, drop", 0)]
    r = qos.ratios(rows, lost)
    assert r["p50 no table / flood, table"] == 20.0 and r["p99 no table / flood, table"] == 100.0
    assert r["lost best-effort, drop / reliable, block"] == "inf"  # none lost with reliable + block
    assert r["lost reliable, drop / reliable, block"] == 1.0
    assert "from the CAN stamp: p99 no table / flood, table" not in r  # only where both runs have the stamps
    rows[1]["from_can_stamp"] = {"p50_us": 300, "p99_us": 8000}
    rows[2]["from_can_stamp"] = {"p50_us": 100, "p99_us": 400}
    r = qos.ratios(rows, lost)
    assert r["from the CAN stamp: p50 no table / flood, table"] == 3.0
    assert r["from the CAN stamp: p99 no table / flood, table"] == 20.0
    assert not any("alone" in k for k in r)
    md = qos.table_md(rows, lost, r)
    assert "| flood, table | `t` | 250 |" in md and "| best-effort, drop | 300/1000 | 30.0 |" in md
