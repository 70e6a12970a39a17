"""The viewer decodes each bus with its own DBC (a scenario's buses[].dbc): the bus is the one
its keys name (<prefix>/<bus>/rx), or a recording's /can/<bus> topic; a bus without one of its
own falls back to --dbc. Two DBCs that describe the same id (0x2F0) differently prove which one
decoded a frame. compose gives the viewer service every bus's own DBC (--bus-dbc BUS=FILE), and
bad --bus-dbc specs are refused naming them."""
from __future__ import annotations

import shutil
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest

from canbench import compose, scenario, wire
from canbench.dbc import load_dbc
from canbench.errors import InputError

pytestmark = pytest.mark.unit
rr = pytest.importorskip("rerun", reason="the viewer needs rerun-sdk (pip install -e '.[viewer]')")

from canbench import viewer  # noqa: E402
from canbench.viewer import Sample, Viewer, read_rrd_columns  # noqa: E402
from canbench.viewer_types import LOGGERS, Context  # noqa: E402
from canbench.viewer_types.can import CanColumns  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
POWERTRAIN = REPO / "scenarios" / "dbc" / "powertrain.dbc"  # 0x2F0 GearboxState: Counter, oil pressure, Checksum
UNIT = REPO / "tests" / "data" / "dbc" / "signals.dbc"       # 0x2F0 GearboxState: Gear, oil pressure; 0x500 DoorEvent
GEARBOX = wire.Frame(0x2F0, 6, bytes([0x13, 0x19, 0, 0, 0, 0xAB]))  # powertrain: Counter 3; unit DBC: Gear 3
DOOR = wire.Frame(0x500, 1, bytes([0x01]))                          # the unit DBC only: DoorOpen 1


def signals_of(columns: dict, base: str) -> dict[str, float]:
    """<base>/<id>/<signal> -> its first scalar, for every decoded signal under base."""
    base = "/" + base.strip("/")  # Rerun's entity paths, read back, start with /
    return {entity[len(base) + 1:]: values["Scalars:scalars"][0][0] for entity, values in columns.items()
            if entity.startswith(base + "/") and "Scalars:scalars" in values}


def test_each_bus_is_decoded_with_its_own_dbc(tmp_path):
    path = tmp_path / "view.rrd"
    live = Viewer(None, [], True, dbc=load_dbc(POWERTRAIN), bus_dbcs={"vcan1": load_dbc(UNIT)})  # type: ignore[arg-type]
    for i, bus in enumerate(("vcan0", "vcan1", "vcan2")):  # vcan2: no DBC of its own
        payload = wire.encode(GEARBOX) + wire.encode(DOOR)
        live.samples.put(Sample(1_700_000_000_000_000_000 + i, f"vehicle/can/{bus}/rx", payload))
    live.samples.put(None)
    rec = rr.RecordingStream("canbench-test-bus-dbc")
    rec.save(str(path))
    with rec:
        live._log_loop()
        # a recording's can_msgs/msg/Frame topic /can/<bus>: the same choice by bus
        for bus in ("vcan0", "vcan1"):
            msg = SimpleNamespace(id=0x2F0, dlc=6, data=list(GEARBOX.data) + [0, 0], is_rtr=False, is_extended=False,
                                  is_error=False)
            LOGGERS["can_msgs/msg/Frame"](live.ctx, f"mcap/can/{bus}", msg)
        live.can.flush()  # the viewer's columns: sent when due, here at once
    rec.flush()
    rec.disconnect()
    columns = read_rrd_columns(path)
    assert live.logged == 3 and not live.malformed
    powertrain = {"2F0/Counter": 3.0, "2F0/GearboxOilPressure": 2.5, "2F0/Checksum": 0xAB}
    assert signals_of(columns, "can/rx/vcan0") == powertrain  # DoorEvent: not in its DBC, raw only
    assert signals_of(columns, "can/rx/vcan1") == {"2F0/Gear": 3.0, "2F0/GearboxOilPressure": 2.5, "500/DoorOpen": 1.0}
    assert signals_of(columns, "can/rx/vcan2") == powertrain  # the default DBC
    for bus in ("vcan0", "vcan1", "vcan2"):  # every frame still raw
        assert {f"/can/rx/{bus}/2F0/raw", f"/can/rx/{bus}/500/raw"} <= set(columns)
    assert set(signals_of(columns, "mcap/can/vcan0")) == set(powertrain)
    assert set(signals_of(columns, "mcap/can/vcan1")) == {"2F0/Gear", "2F0/GearboxOilPressure"}


def test_a_bus_without_any_dbc_is_only_raw():
    ctx = Context(None, {"vcan1": load_dbc(UNIT)})
    columns = CanColumns(ctx.dbc, ctx.bus_dbcs)
    columns.add("can/rx/vcan0", 1, [GEARBOX])
    columns.add("can/rx/vcan1", 1, [GEARBOX])
    assert sorted(columns.signals) == ["can/rx/vcan1/2F0/Gear", "can/rx/vcan1/2F0/GearboxOilPressure"]
    assert sorted(columns.raw) == ["can/rx/vcan0/2F0/raw", "can/rx/vcan1/2F0/raw"]


def two_bus_scenario(tmp_path: Path, top_level: bool) -> Path:
    (tmp_path / "dbc").mkdir()
    shutil.copy(POWERTRAIN, tmp_path / "dbc" / "powertrain.dbc")
    shutil.copy(UNIT, tmp_path / "dbc" / "body.dbc")
    (tmp_path / "traces").mkdir()
    shutil.copy(REPO / "scenarios" / "traces" / "powertrain-2s.log", tmp_path / "traces")
    path = tmp_path / "two.yaml"
    path.write_text(textwrap.dedent(f"""\
        name: two
        duration_s: 5
        {"dbc: dbc/powertrain.dbc" if top_level else ""}
        buses:
          - name: vcan0
          - name: vcan1
            dbc: dbc/body.dbc
          - name: vcan2
            {"" if top_level else "dbc: dbc/powertrain.dbc"}
        ecus:
          - name: engine
            bus: vcan0
            trace: traces/powertrain-2s.log
        bridge: {{mode: client, publish_period_ms: 0}}
        expect: {{integrity: true}}
        """))
    return path


@pytest.mark.parametrize("top_level", [True, False], ids=["with-top-level-dbc", "per-bus-only"])
def test_compose_gives_the_viewer_each_buses_dbc(tmp_path, top_level):
    sc = scenario.load(two_bus_scenario(tmp_path, top_level))
    command = compose.compose_override(sc, "/scenarios/two.yaml", viewer=True, can_mode="userspace")[
        "services"]["viewer"]["command"]
    pairs = [(a, b) for a, b in zip(command, command[1:], strict=False) if a in ("--dbc", "--bus-dbc")]
    if top_level:  # vcan0 and vcan2 take the top-level one
        assert pairs == [("--dbc", "/scenarios/dbc/powertrain.dbc"), ("--bus-dbc", "vcan1=/scenarios/dbc/body.dbc")]
    else:  # no default: each bus names its own
        assert pairs == [("--bus-dbc", "vcan1=/scenarios/dbc/body.dbc"),
                         ("--bus-dbc", "vcan2=/scenarios/dbc/powertrain.dbc")]


def test_compose_viewer_dbc_from_a_relative_scenario_path(tmp_path, monkeypatch):
    two_bus_scenario(tmp_path, True)
    monkeypatch.chdir(tmp_path)
    sc = scenario.load("two.yaml")  # as `canbench run two.yaml` names it
    command = compose.compose_override(sc, "/scenarios/two.yaml", viewer=True, can_mode="userspace")[
        "services"]["viewer"]["command"]
    assert "vcan1=/scenarios/dbc/body.dbc" in command and "/scenarios/dbc/powertrain.dbc" in command


def test_bad_bus_dbc_specs_are_refused(tmp_path):
    assert viewer.bus_dbc_paths([f"vcan1={UNIT}"]) == {"vcan1": UNIT}
    for spec, message in ((str(UNIT), "expected BUS=FILE"), (f"={UNIT}", "expected BUS=FILE"),
                          ("vcan1=", "expected BUS=FILE"), (f"a/b={UNIT}", "expected BUS=FILE"),
                          (f"vcan1={tmp_path / 'none.dbc'}", "--bus-dbc vcan1: no such file")):
        with pytest.raises(InputError, match=message):
            viewer.bus_dbc_paths([spec])
    with pytest.raises(InputError, match="bus vcan1 given twice"):
        viewer.bus_dbc_paths([f"vcan1={UNIT}", f"vcan1={POWERTRAIN}"])
