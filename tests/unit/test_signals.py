"""Signal expectations (canbench/signals.py): each operator on hand-made decoded series, scaled,
signed, float, multiplexed and value-table signals from tests/data/dbc/signals.dbc; the
scenario's signal keys refused at their file:line; and a seeded fault: one bit flipped inside one
signal of one frame on the Zenoh side fails exactly that signal's check (and integrity)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import cantools
import pytest

from canbench import analysis, checks, oracle, scenario, signals, wire
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "tests" / "data" / "dbc" / "signals.dbc"
T0 = 1_700_000_000_000_000_000


_DB = cantools.database.load_file(str(DBC))


def db():
    return _DB


def frame(message: str, **values) -> wire.Frame:
    m = db().get_message_by_name(message)
    data = m.encode({s.name: 0 for s in m.signals if s.multiplexer_ids is None} | values, strict=False)
    return wire.Frame(m.frame_id, len(data), bytes(data), m.is_extended_frame)


def write_scenario(tmp: Path, expect: str, buses: str = "  - name: vcan0\n", top_dbc: bool = True) -> Path:
    (tmp / "dbc").mkdir(exist_ok=True)
    shutil.copy(DBC, tmp / "dbc" / "signals.dbc")
    (tmp / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 0C0#0000000000000000\n")
    path = tmp / "sc.yaml"
    path.write_text("name: sig\nduration_s: 10\n" + ("dbc: dbc/signals.dbc\n" if top_dbc else "")
                    + "buses:\n" + buses
                    + "ecus:\n  - name: engine\n    bus: vcan0\n    trace: trace.log\nexpect:\n" + expect)
    return path


def gates_of(tmp: Path, signals_yaml: str):
    return scenario.load(write_scenario(tmp, "  signals:\n" + signals_yaml)).signal_gates


def run_of(gates, frames: list[tuple[int, wire.Frame]], zenoh: list[tuple[int, wire.Frame]] | None = None):
    """A hand-made run: bus frames (ms, frame) at can.log lines 1.., the same on Zenoh unless given."""
    bus = [oracle.Observed(f, T0 + int(ms * 1e6), i, line=i + 1) for i, (ms, f) in enumerate(frames)]
    zen_src = zenoh if zenoh is not None else frames
    zen = [oracle.Observed(f, T0 + int(ms * 1e6) + 400_000, i, key="vehicle/can/rx", seq=i)
           for i, (ms, f) in enumerate(zen_src)]
    matched = [(s, r) for s, r in zip(bus, zen, strict=False) if s.frame == r.frame]
    sc = SimpleNamespace(signal_gates=gates, bus_dbcs={"vcan0": DBC}, expect={})
    b = SimpleNamespace(bus="vcan0", bus_frames=bus, can_frames=bus, zenoh_frames=zen,
                        comparison=SimpleNamespace(matched=matched, corrupted=[]))
    return SimpleNamespace(scenario=sc, buses=[b], metrics={})


# ---- operators on hand-made series ----

def test_range_on_a_scaled_signal_names_value_unit_time_and_line(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineSpeed: {range: [0, 8000]}\n")
    r = run_of(gates, [(0, frame("EngineData", EngineSpeed=800)), (10, frame("EngineData", EngineSpeed=8000)),
                       (3214, frame("EngineData", EngineSpeed=16383)), (3224, frame("EngineData", EngineSpeed=900))])
    problems = checks.signals_can(r)
    assert len(problems) == 1
    assert "EngineData.EngineSpeed = 16383 rpm outside [0, 8000] at t=3.214 s, can.log:3" in problems[0]
    assert "1 violation:" in problems[0]


def test_offset_signal_range_uses_the_physical_value(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineTorque: {range: [-20, 50]}\n")
    ok = run_of(gates, [(0, frame("EngineData", EngineTorque=-20)), (10, frame("EngineData", EngineTorque=50))])
    assert checks.signals_can(ok) == []
    bad = run_of(gates, [(0, frame("EngineData", EngineTorque=-21))])
    assert "EngineTorque = -21 Nm outside [-20, 50]" in checks.signals_can(bad)[0]


def test_equals_and_one_of_by_value_table_name(tmp_path):
    gates = gates_of(tmp_path, "    GearboxState.Gear: {one_of: [P, R, N, D]}\n"
                               "    GearboxState.GearboxOilPressure: {equals: 2.5}\n")
    good = [(i * 50, frame("GearboxState", Gear=g, GearboxOilPressure=2.5)) for i, g in enumerate([0, 1, 2, 3])]
    assert checks.signals_can(run_of(gates, good)) == []
    bad = run_of(gates, good + [(200, frame("GearboxState", Gear=7, GearboxOilPressure=2.6))])
    problems = checks.signals_can(bad)
    assert len(problems) == 2
    assert any("GearboxState.Gear = 7 not one of [P, R, N, D] at t=0.200 s, can.log:5" in p for p in problems)
    assert any("GearboxOilPressure = 2.6 bar, expected 2.5 bar" in p for p in problems)


def test_equals_a_name_shows_the_name(tmp_path):
    gates = gates_of(tmp_path, "    GearboxState.Gear: {equals: D}\n")
    problems = checks.signals_can(run_of(gates, [(0, frame("GearboxState", Gear=1, GearboxOilPressure=0))]))
    assert "GearboxState.Gear = 1 (R), expected 3 (D)" in problems[0]


def test_max_rate_per_second(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineSpeed: {max_rate: 10000}\n")
    steady = [(i * 10, frame("EngineData", EngineSpeed=1000 + 100 * i)) for i in range(5)]  # 10000 rpm/s
    assert checks.signals_can(run_of(gates, steady)) == []
    jump = steady + [(50, frame("EngineData", EngineSpeed=1600))]  # +200 rpm in 10 ms: 20000 rpm/s
    problems = checks.signals_can(run_of(gates, jump))
    assert "EngineSpeed changed 1400 rpm -> 1600 rpm in 10.000 ms (20000/s > 10000/s) at t=0.050 s, can.log:6" \
        in problems[0]


def test_max_rate_on_zenoh_is_judged_at_the_bus_stamps_of_a_batch(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineSpeed: {max_rate: 10000}\n")
    steady = [(i * 10, frame("EngineData", EngineSpeed=1000 + 100 * i)) for i in range(5)]  # 10000 rpm/s
    batch = [(50, f) for _, f in steady]  # all five in one sample: one receive time
    assert checks.signals_zenoh(run_of(gates, steady, zenoh=batch)) == []
    unpaired = batch[:2] + [(50, frame("EngineData", EngineSpeed=5000))]  # no bus frame: at its receive time
    assert "EngineSpeed changed 1100 rpm -> 5000 rpm in 40.400 ms (96534.7/s > 10000/s) at t=0.050 s, zenoh #2" \
        in checks.signals_zenoh(run_of(gates, steady, zenoh=unpaired))[0]


def test_present_counts_per_side(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.Counter: {present: 3}\n")
    frames = [(i * 10, frame("EngineData", Counter=i)) for i in range(3)]
    assert checks.signals_can(run_of(gates, frames)) == []
    problems = checks.signals_zenoh(run_of(gates, frames, zenoh=frames[:2]))
    assert problems == ["vcan0 EngineData.Counter: 1 violation: EngineData.Counter seen 2 times on Zenoh vcan0, "
                        "expected at least 3"]
    assert checks.signals_can(run_of(gates, frames, zenoh=frames[:2])) == []


def test_a_gate_that_judged_nothing_fails_where_the_values_went_missing(tmp_path):
    """A range on a message the bus never carried passed with no value judged; now the bus side
    says so, and Zenoh only when the bus had the values."""
    gates = gates_of(tmp_path, "    Chassis.LongAccel: {range: [-2, 2]}\n")
    other = [(0, frame("EngineData", Counter=1))]
    nothing = "vcan0 Chassis.LongAccel: no value on the bus, so the gate judged nothing (Chassis never sent"
    assert checks.signals_can(run_of(gates, other))[0].startswith(nothing)
    assert checks.signals_zenoh(run_of(gates, other)) == []  # the sender's, said once
    sent = [(0, frame("Chassis", LongAccel=1.0))]
    assert checks.signals_can(run_of(gates, sent, zenoh=other)) == []
    assert checks.signals_zenoh(run_of(gates, sent, zenoh=other))[0].startswith(
        "vcan0 Chassis.LongAccel: no value on Zenoh, so the gate judged nothing (Chassis never arrived")


def test_signed_and_float_signals_on_an_extended_id(tmp_path):
    gates = gates_of(tmp_path, "    Chassis.LongAccel: {range: [-2, 2]}\n    Chassis.YawRate: {range: [-10.5, 10.5]}\n")
    ok = [(0, frame("Chassis", LongAccel=-1.5, YawRate=-10.25)), (100, frame("Chassis", LongAccel=1.99, YawRate=10.5))]
    assert checks.signals_can(run_of(gates, ok)) == []
    problems = checks.signals_can(run_of(gates, [(0, frame("Chassis", LongAccel=-2.01, YawRate=10.75))]))
    assert any("Chassis.LongAccel = -2.01 m/s2 outside [-2, 2]" in p for p in problems)
    assert any("Chassis.YawRate = 10.75 deg/s outside [-10.5, 10.5]" in p for p in problems)


def test_multiplexed_signals_are_judged_only_in_their_pages(tmp_path):
    gates = gates_of(tmp_path, "    Diag.CoolantTemp: {range: [-10, 120], present: 2}\n"
                               "    Diag.OilPressure: {range: [100, 500]}\n")
    pages = [(0, frame("Diag", Page=0, CoolantTemp=90)), (100, frame("Diag", Page=1, OilPressure=300.5)),
             (200, frame("Diag", Page=0, CoolantTemp=95)), (300, frame("Diag", Page=1, OilPressure=250))]
    run = signals.evaluate(run_of(gates, pages))
    assert run.problems("can") == []
    stats = run.summary()["can"]["vcan0"]
    assert stats["Diag.CoolantTemp"] | {"limits": None} == {"count": 2, "min": 90.0, "max": 95.0, "violations": 0,
                                                            "limits": None, "unit": "degC"}
    assert stats["Diag.OilPressure"]["count"] == 2 and stats["Diag.OilPressure"]["min"] == 250.0
    bad = pages + [(400, frame("Diag", Page=1, OilPressure=600))]
    assert "Diag.OilPressure = 600 kPa outside [100, 500]" in checks.signals_can(run_of(gates, bad))[0]


def test_a_frame_that_does_not_decode_is_a_violation_of_its_gated_signals(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineSpeed: {range: [0, 8000]}\n")
    short = wire.Frame(0x0C0, 2, b"\x00\x01")
    problems = checks.signals_can(run_of(gates, [(0, short)]))
    assert "EngineData.EngineSpeed: EngineData frame 0C0#0001 does not decode" in problems[0]


def test_violations_are_bounded_and_the_rest_counted(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.EngineSpeed: {range: [0, 100]}\n")
    frames = [(i, frame("EngineData", EngineSpeed=1000)) for i in range(signals.MAX_VIOLATIONS + 30)]
    run = signals.evaluate(run_of(gates, frames))
    s = run.of("can")[0]
    assert len(s.violations) == signals.MAX_VIOLATIONS and s.more == 30 and s.violation_count == len(frames)
    assert run.problems("can")[0].endswith("; ... (30 more)")


def test_the_plotted_series_is_thinned_to_a_bound(tmp_path):
    gates = gates_of(tmp_path, "    EngineData.Counter: {range: [0, 15]}\n")
    series = signals.Series(gates[0], "can", "vcan0")
    for i in range(20 * signals.PLOT_POINTS):
        series.add(T0 + i * 1_000_000, T0, float(i % 16), lambda: "")
    assert len(series.points) < signals.PLOT_POINTS and series.count == 20 * signals.PLOT_POINTS
    assert series.points[0] == (0.0, 0.0) and series.min == 0 and series.max == 15


# ---- validation at load time: file:line, nothing run ----

@pytest.mark.parametrize("signals_yaml, line, message", [
    ("    EngineData.EngineSped: {range: [0, 1]}\n", 12,
     "expect.signals.EngineData.EngineSped: message EngineData has no signal EngineSped (it has Counter, EngineSpeed"),
    ("    EngineDat.EngineSpeed: {range: [0, 1]}\n", 12, "no message EngineDat in the DBC of vcan0"),
    ("    GearboxState.Gear:\n      one_of: [P, X]\n", 13,
     "expect.signals.GearboxState.Gear.one_of.1: 'X' is not in GearboxState.Gear's value table (P, R, N, D)"),
    ("    EngineData.EngineSpeed:\n      range: [10, 1]\n", 13, "min 10 is above max 1"),
    ("    EngineData.EngineSpeed:\n      equals: fast\n", 13, "(it has none)"),
    ("    EngineData.EngineSpeed:\n      rang: [0, 1]\n", 13, "Additional properties are not allowed ('rang'"),
    ("    EngineSpeed: {range: [0, 1]}\n", 12, "'EngineSpeed' does not match"),
    ("    EngineData.EngineSpeed: {buses: [vcan0]}\n", 12,
     "nothing to judge: give at least one of range, equals, one_of, max_rate, present"),
])
def test_names_the_dbc_lacks_are_errors_at_their_line(tmp_path, signals_yaml, line, message):
    with pytest.raises(ScenarioError) as e:
        gates_of(tmp_path, signals_yaml)
    assert e.value.line == line
    assert str(e.value).startswith(f"{tmp_path / 'sc.yaml'}:{line}: ")
    assert message in str(e.value)


def test_a_bus_without_a_dbc_and_a_bad_dbc_are_errors(tmp_path):
    with pytest.raises(ScenarioError, match=r"sc.yaml:11: expect.signals.EngineData.Counter: needs a DBC"):
        scenario.load(write_scenario(tmp_path, "  signals:\n    EngineData.Counter: {present: 1}\n", top_dbc=False))
    (tmp_path / "dbc").mkdir(exist_ok=True)
    (tmp_path / "dbc" / "broken.dbc").write_text("BO_ 12 x y z\n")
    with pytest.raises(ScenarioError, match=r"sc.yaml:5: buses.0.dbc: cannot load broken.dbc as a DBC"):
        scenario.load(write_scenario(tmp_path, "  integrity: true\n",
                                     buses="  - name: vcan0\n    dbc: dbc/broken.dbc\n", top_dbc=False))
    with pytest.raises(ScenarioError, match=r"sc.yaml:5: buses.0.dbc: no such file"):
        scenario.load(write_scenario(tmp_path, "  integrity: true\n",
                                     buses="  - name: vcan0\n    dbc: dbc/none.dbc\n", top_dbc=False))


def test_per_bus_dbc_overrides_the_default_and_gates_follow_the_message(tmp_path):
    (tmp_path / "dbc").mkdir()
    shutil.copy(REPO / "scenarios" / "dbc" / "powertrain.dbc", tmp_path / "dbc" / "powertrain.dbc")
    sc = scenario.load(write_scenario(
        tmp_path, "  signals:\n    Diag.CoolantTemp: {range: [0, 90]}\n"
                  "    EngineData.EngineSpeed: {range: [0, 9000]}\n",
        buses="  - name: vcan0\n  - name: vcan1\n    dbc: dbc/powertrain.dbc\n"))
    assert sc.bus_dbcs == {"vcan0": (tmp_path / "dbc" / "signals.dbc").resolve(),
                           "vcan1": (tmp_path / "dbc" / "powertrain.dbc").resolve()}
    by_key = {g.key: g.buses for g in sc.signal_gates}
    assert by_key == {"Diag.CoolantTemp": ("vcan0",), "EngineData.EngineSpeed": ("vcan0", "vcan1")}
    with pytest.raises(ScenarioError, match=r"sc.yaml:16: expect.signals.Diag.CoolantTemp.buses: the DBC of vcan1 "
                                            r"has no message Diag"):
        scenario.load(write_scenario(
            tmp_path, "  signals:\n    Diag.CoolantTemp:\n      range: [0, 90]\n      buses: [vcan0, vcan1]\n",
            buses="  - name: vcan0\n  - name: vcan1\n    dbc: dbc/powertrain.dbc\n"))


def test_a_signal_only_one_buses_dbc_has_is_judged_there(tmp_path):
    (tmp_path / "dbc").mkdir()
    shutil.copy(REPO / "scenarios" / "dbc" / "powertrain.dbc", tmp_path / "dbc" / "powertrain.dbc")
    two = "  - name: vcan0\n  - name: vcan1\n    dbc: dbc/powertrain.dbc\n"
    # GearboxState is in both DBCs; Gear only in signals.dbc (powertrain's has GearboxOilPressure only)
    sc = scenario.load(write_scenario(tmp_path, "  signals:\n    GearboxState.Gear: {one_of: [P, D]}\n", buses=two))
    assert [g.buses for g in sc.signal_gates] == [("vcan0",)]
    with pytest.raises(ScenarioError, match=r"sc.yaml:16: expect.signals.GearboxState.Gear.buses: message "
                                            r"GearboxState in the DBC of vcan1 has no signal Gear"):
        scenario.load(write_scenario(tmp_path, "  signals:\n    GearboxState.Gear:\n      one_of: [P, D]\n"
                                               "      buses: [vcan0, vcan1]\n", buses=two))


def test_validate_exits_2_on_a_missing_signal(tmp_path):
    path = write_scenario(tmp_path, "  signals:\n    EngineData.Speed: {range: [0, 1]}\n")
    proc = subprocess.run([sys.executable, "-m", "canbench.cli", "validate", str(path)], capture_output=True,
                          text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 2
    assert f"{path}:12: expect.signals.EngineData.Speed: message EngineData has no signal Speed" in proc.stderr


# ---- a seeded fault through the real analysis: one bit flipped inside one signal ----

def flipped_run(tmp_path: Path) -> tuple[analysis.RunResult, int]:
    """A run through the real analysis: 2 s of EngineData, GearboxState and Diag frames, the Zenoh
    side with one bit flipped inside EngineSpeed of one frame (its index returned)."""
    path = write_scenario(tmp_path, "  integrity: true\n  ordering: true\n  signals:\n"
                                    "    EngineData.EngineSpeed: {range: [0, 8000]}\n"
                                    "    EngineData.EngineTorque: {range: [-125, 130]}\n"
                                    "    GearboxState.Gear: {one_of: [P, R, N, D]}\n"
                                    "    Diag.CoolantTemp: {range: [-40, 130]}\n")
    sc = scenario.load(path)
    frames = []
    for i in range(200):
        frames.append((i * 10, frame("EngineData", Counter=i % 16, EngineSpeed=800 + 10 * i, EngineTorque=20)))
        if i % 5 == 0:
            frames.append((i * 10 + 1, frame("GearboxState", Gear=3, GearboxOilPressure=2.5)))
        if i % 20 == 0:
            frames.append((i * 10 + 2, frame("Diag", Page=0, CoolantTemp=90)))
    # an EngineData frame in the middle; bit 7 of byte 2 is EngineSpeed's top bit (+8192 rpm)
    flipped = next(i for i in range(len(frames) // 2, len(frames)) if frames[i][1].can_id == 0x0C0)
    with open(tmp_path / "can.log", "w") as f:
        for ms, fr in frames:
            t = T0 + ms * 1_000_000
            f.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {fr.candump('vcan0')}\n")
    with open(tmp_path / "zenoh.tsv", "w") as f:
        for i, (ms, fr) in enumerate(frames):
            if i == flipped:
                data = bytearray(fr.data)
                data[2] ^= 0x80
                fr = wire.Frame(fr.can_id, fr.dlc, bytes(data), fr.extended)
            t = T0 + ms * 1_000_000
            f.write(f"{t + 400_000}\tvehicle/can/rx\t{wire.encode(fr).hex()}\t{wire.encode_attachment(i, [t]).hex()}\n")
    result = analysis.analyse(sc, "flip", tmp_path, "vehicle/can", {"engine": {"sent": len(frames), "role": "replay",
                                                                               "bus": "vcan0"}},
                              {"buses": [{"bus": "vcan0", "published_frames": len(frames), "tx_frames": 0}]}, 2.0)
    return result, flipped


def test_one_flipped_bit_fails_exactly_that_signals_zenoh_check_and_integrity(tmp_path):
    result, flipped = flipped_run(tmp_path)
    failing = checks.failing(result)
    assert set(failing) == {"integrity", "signals_zenoh"}, failing
    assert len(failing["signals_zenoh"]) == 1
    problem = failing["signals_zenoh"][0]
    assert problem.startswith("vcan0 EngineData.EngineSpeed: 1 violation: EngineData.EngineSpeed = ")
    assert "rpm outside [0, 8000] at t=" in problem and f"(sent as can.log:{flipped + 1})" in problem
    metrics = result.metrics["signals"]
    assert metrics["zenoh"]["vcan0"]["EngineData.EngineSpeed"]["violations"] == 1
    assert metrics["can"]["vcan0"]["EngineData.EngineSpeed"]["violations"] == 0
    assert metrics["can"]["vcan0"]["GearboxState.Gear"] == {"count": 40, "min": 3.0, "max": 3.0, "violations": 0,
                                                            "limits": "one of [P, R, N, D]", "unit": ""}


# ---- cycle_time from the DBC ----

def cycle_result(gate: dict, sides: dict[str, tuple[float, float]]):
    """Per id (bus median, Zenoh median) in ms, 50 frames each."""
    def stats(p50):
        return {"count": 50, "cycle_p50_ms": p50, "cycle_min_ms": p50, "cycle_max_ms": p50}
    times = {ident: {"can": stats(can), "zenoh": stats(zen)} for ident, (can, zen) in sides.items()}
    return SimpleNamespace(scenario=SimpleNamespace(expect={"cycle_time": gate}, bus_dbcs={"vcan0": DBC}),
                           buses=[SimpleNamespace(bus="vcan0", cycle_times=times)], metrics={})


def test_cycle_time_from_dbc_judges_cyclic_messages_on_both_sides():
    sides = {"0C0": (10.1, 10.2), "2F0": (80.0, 80.0), "18FEF100": (100.0, 130.0), "500": (3.0, 7.0),
             "123": (1.0, 900.0)}
    problems = checks.cycle_time(cycle_result({"from_dbc": True, "tolerance_pct": 20}, sides))
    assert problems == [  # the sender's wrong cycle said once, on the bus: the bridge kept it
        "vcan0 id 2F0 (GearboxState): median cycle 80.00 ms on the bus, the DBC says 50.00 ms +-20%",
        "vcan0 id 18FEF100: median cycle 130.00 ms on Zenoh, expected 100.00 ms +-20%"]
    # ... and a bridge that also changes it is judged against the bus's cycle
    assert checks.cycle_time(cycle_result({"from_dbc": True, "tolerance_pct": 20}, {"2F0": (80.0, 110.0)})) == [
        "vcan0 id 2F0 (GearboxState): median cycle 80.00 ms on the bus, the DBC says 50.00 ms +-20%",
        "vcan0 id 2F0: median cycle 110.00 ms on Zenoh, expected 80.00 ms +-20%"]
    # ids: still override the database; without from_dbc the bus median is the reference, as before
    assert checks.cycle_time(cycle_result({"from_dbc": True, "tolerance_pct": 20, "ids": {"2F0": 80}},
                                          {"2F0": (80.0, 80.0)})) == []
    assert checks.cycle_time(cycle_result({"tolerance_pct": 20}, {"2F0": (80.0, 80.0)})) == []


def test_an_event_periodic_cycle_is_the_longest_gap_not_the_rhythm(tmp_path):
    """EventPeriodic (a cycle plus events in between): its median is the events', so the DBC's
    cycle is judged as the longest gap on the bus; Zenoh keeps the bus's rhythm."""
    dbc_file = tmp_path / "ev.dbc"
    dbc_file.write_text('VERSION ""\nBU_: GW\nBO_ 118 Brake: 8 GW\n SG_ B : 0|8@1+ (1,0) [0|0] "" GW\n'
                        'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;\n'
                        'BA_DEF_ BO_ "GenMsgSendType" ENUM "Cyclic","EventPeriodic";\n'
                        'BA_DEF_DEF_ "GenMsgCycleTime" 0;\nBA_DEF_DEF_ "GenMsgSendType" "Cyclic";\n'
                        'BA_ "GenMsgCycleTime" BO_ 118 500;\nBA_ "GenMsgSendType" BO_ 118 1;\n')

    def result(can_p50, can_max, zen_p50):
        def stats(p50, top):
            return {"count": 50, "cycle_p50_ms": p50, "cycle_min_ms": p50, "cycle_max_ms": top}
        times = {"076": {"can": stats(can_p50, can_max), "zenoh": stats(zen_p50, can_max)}}
        return SimpleNamespace(scenario=SimpleNamespace(expect={"cycle_time": {"from_dbc": True, "tolerance_pct": 20}},
                                                        bus_dbcs={"vcan0": dbc_file}),
                               buses=[SimpleNamespace(bus="vcan0", cycle_times=times)], metrics={})
    assert checks.cycle_time(result(20.0, 480.0, 20.0)) == []  # events every 20 ms, never a gap over 500
    assert checks.cycle_time(result(20.0, 700.0, 20.0)) == [
        "vcan0 id 076 (Brake): longest gap 700.00 ms on the bus, the DBC's cycle of an event-periodic message "
        "(the most it may be) 500.00 ms +-20%"]
    assert checks.cycle_time(result(20.0, 480.0, 40.0)) == [
        "vcan0 id 076: median cycle 40.00 ms on Zenoh, expected 20.00 ms +-20%"]


def test_from_dbc_needs_a_dbc(tmp_path):
    with pytest.raises(ScenarioError, match=r"sc.yaml:11: expect.cycle_time.from_dbc: needs a DBC"):
        scenario.load(write_scenario(tmp_path, "  cycle_time:\n    from_dbc: true\n", top_dbc=False))
    sc = scenario.load(write_scenario(tmp_path, "  cycle_time: {from_dbc: true, tolerance_pct: 20}\n"))
    assert sc.expect["cycle_time"]["from_dbc"] is True


def test_readmes_scenario_example_loads_with_its_signal_expectations(tmp_path):
    """README's scenario (Writing a scenario) is a valid scenario: its signal names are in the DBC."""
    text = (REPO / "README.md").read_text().split("\n## Writing a scenario\n", 1)[1]
    block = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    (tmp_path / "dbc").mkdir()
    shutil.copy(REPO / "scenarios" / "dbc" / "powertrain.dbc", tmp_path / "dbc")
    (tmp_path / "traces").mkdir()
    shutil.copy(REPO / "scenarios" / "traces" / "powertrain-2s.log", tmp_path / "traces" / "my-drive.log")
    for path in (REPO / "scenarios").rglob("*"):  # anything else it names (traces, CSVs) as shipped
        if path.is_file() and not (tmp_path / path.relative_to(REPO / "scenarios")).exists():
            (tmp_path / path.relative_to(REPO / "scenarios")).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, tmp_path / path.relative_to(REPO / "scenarios"))
    (tmp_path / "my-drive.yaml").write_text(block)
    sc = scenario.load(tmp_path / "my-drive.yaml")
    assert {g.key for g in sc.signal_gates} >= {"EngineData.EngineSpeed", "PedalData.PedalPosition"}
