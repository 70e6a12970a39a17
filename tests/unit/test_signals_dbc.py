"""Large real-world DBCs (cantools' own vehicle.dbc: 217 messages, all 29-bit; abs.dbc:
multiplexed, value tables) and a generated one (cantools' API: 29-bit, multiplexed, scaled,
signed, float) load, validate a scenario's gates and decode within a bound; make bench measures
the same at scale (bench/dbc.py)."""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import cantools
import pytest

from bench import dbc as bench_dbc
from canbench import dbc, scenario, signals
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
CANTOOLS = REPO / "tests" / "data" / "dbc" / "cantools"
BOUND_S = 10.0  # load + 5000 frames judged on every signal; ~0.5 s on a loaded 2-core machine


@pytest.mark.parametrize("name", ["vehicle", "abs"])
def test_a_large_dbc_loads_and_every_signal_is_judged_in_bounded_time(name):
    t = time.perf_counter()
    db = cantools.database.load_file(str(CANTOOLS / f"{name}.dbc"))  # not load_dbc's cache: the time of a load
    frames = bench_dbc.frames_of(db, 5000)
    evaluator = signals.Evaluator(bench_dbc.every_signal(db), db, "can", "vcan0", 0)
    for i, f in enumerate(frames):
        evaluator.feed(f, i * 1_000_000, "x")
    series = evaluator.finish()
    assert time.perf_counter() - t < BOUND_S
    assert sum(s.count for s in series) > 5000 and not any(s.violation_count for s in series)


def test_the_shipped_large_dbcs_shapes():
    vehicle = dbc.load_dbc(CANTOOLS / "vehicle.dbc")
    assert len(vehicle.messages) >= 200 and all(m.is_extended_frame for m in vehicle.messages)
    abs_db = dbc.load_dbc(CANTOOLS / "abs.dbc")
    assert any(m.is_multiplexed() for m in abs_db.messages)
    assert (CANTOOLS / "LICENSE").read_text().startswith("The MIT License")


def test_a_generated_dbc_of_hundreds_of_messages_round_trips_through_cantools(tmp_path):
    path = tmp_path / "generated.dbc"
    path.write_text(bench_dbc.generated_dbc(300))
    result = bench_dbc.measure("generated", path, 3000)
    assert (result["messages"], result["extended"], result["multiplexed"]) == (300, 150, 75)
    assert result["violations"] == 0 and result["values"] > 3000
    assert result["max_points"] <= signals.PLOT_POINTS


def test_a_scenario_on_a_large_dbc_validates_its_names(tmp_path):
    (tmp_path / "dbc").mkdir()
    shutil.copy(CANTOOLS / "vehicle.dbc", tmp_path / "dbc")
    (tmp_path / "t.log").write_text("(1700000000.000000) vcan0 123#00\n")
    body = ("name: big\nduration_s: 10\nbuses:\n  - name: vcan0\n    dbc: dbc/vehicle.dbc\n"
            "ecus:\n  - name: e\n    bus: vcan0\n    trace: t.log\nexpect:\n  signals:\n")
    (tmp_path / "ok.yaml").write_text(body + "    RT_DL1MK3_Speed.Speed: {range: [0, 100]}\n")
    assert [g.key for g in scenario.load(tmp_path / "ok.yaml").signal_gates] == ["RT_DL1MK3_Speed.Speed"]
    (tmp_path / "bad.yaml").write_text(body + "    RT_DL1MK3_Speed.Sped: {range: [0, 100]}\n")
    with pytest.raises(ScenarioError, match=r"bad.yaml:12: .*message RT_DL1MK3_Speed has no signal Sped"):
        scenario.load(tmp_path / "bad.yaml")
