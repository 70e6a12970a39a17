"""The bridge's QoS table in the bench (canbench/rxqos.py): the bridge's grammar and refusals,
the scenario key bridge.rx_qos (schema + file:line for what the schema cannot see, compose's
ZENOH_RX_QOS), and the ordering check judged per QoS class when the table has several."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from canbench import checks, compose, oracle, rxqos, scenario, wire
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
EXAMPLE = "0x000-0x0FF:realtime,express;0x100-0x7FF:data,best-effort"


def test_classes_as_the_bridge_orders_them():
    t = rxqos.parse(EXAMPLE)
    assert [str(q) for q in t.classes] == ["realtime,express,block,reliable", "data,block,best-effort",
                                           "data,block,reliable"]
    assert str(t.class_of(0x0FF, False)) == "realtime,express,block,reliable"
    assert t.class_of(0x100, False).best_effort and t.class_of(0x050, True) == t.default
    shared = rxqos.parse("0-F:realtime;10-1F:realtime;200-2FF:data")
    assert len(shared.classes) == 2  # equal QoS share a class, a rule equal to the default is the default's
    assert rxqos.parse("e:0-1FFFFFFF:reliable,block,interactive-low", rxqos.Qos(drop=True)).classes[1].drop


def vectors(kind: str) -> list[list[str]]:
    """tests/data/rx_qos_vectors.txt: the bridge's parser (firmware/tests/test_qos.c) holds to the same lines."""
    rows = [line.split("\t") for line in (REPO / "tests" / "data" / "rx_qos_vectors.txt").read_text().splitlines()
            if line and not line.startswith("#")]
    return [row[1:] for row in rows if row[0] == kind]


@pytest.mark.parametrize("table,classes,probes", vectors("ok"))
def test_vectors_classes_and_probes(table, classes, probes):
    t = rxqos.parse(table)
    assert ";".join(map(str, t.classes)) == classes
    for probe in probes.split(";"):
        ident, index = probe.split("=")
        extended = ident.startswith("e:")
        assert t.class_of(int(ident.removeprefix("e:"), 16), extended) == t.classes[int(index)], probe


@pytest.mark.parametrize("table,fragment", vectors("err"))
def test_vectors_refusals_name_the_reason(table, fragment):
    with pytest.raises(rxqos.QosTableError) as e:
        rxqos.parse(table)
    assert str(e.value).startswith("rx QoS table: ") and fragment in str(e.value)


def test_there_are_vectors_of_both_kinds():
    assert len(vectors("ok")) >= 4 and len(vectors("err")) >= 20


def scenario_with(tmp_path: Path, table: str) -> Path:
    text = (REPO / "scenarios" / "smoke.yaml").read_text().replace(
        "bridge:\n  mode: client\n", f"bridge:\n  mode: client\n  rx_qos: \"{table}\"\n")
    (tmp_path / "traces").mkdir()
    (tmp_path / "traces" / "powertrain-2s.log").write_text((REPO / "scenarios" / "traces" / "powertrain-2s.log")
                                                           .read_text())
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "powertrain.dbc").write_text((REPO / "scenarios" / "dbc" / "powertrain.dbc").read_text())
    path = tmp_path / "qos.yaml"
    path.write_text(text)
    return path


def test_the_scenario_key_reaches_the_bridge(tmp_path):
    sc = scenario.load(scenario_with(tmp_path, EXAMPLE))
    env = compose.compose_override(sc, "/scenarios/qos.yaml")["services"]["bridge"]["environment"]
    assert env["ZENOH_RX_QOS"] == EXAMPLE


@pytest.mark.parametrize("table,fragment", [
    ("0-FF:fast", "does not match"),             # the schema: an unknown name
    ("0-FF:realtime;80:data", "overlaps"),       # the bridge's rules: file:line too
    ("800:realtime", "beyond 0x7FF"),
])
def test_a_table_the_bridge_refuses_fails_validation_at_its_line(tmp_path, table, fragment):
    path = scenario_with(tmp_path, table)
    line = path.read_text().splitlines().index(f"  rx_qos: \"{table}\"") + 1
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    assert f"{path}:{line}: bridge.rx_qos: " in str(e.value) and fragment in str(e.value)


def run_result(table: str | None, sent_ids: list[int], arrival: list[int]) -> SimpleNamespace:
    """One bus: frames sent in the order of sent_ids, received in the order of arrival (indexes)."""
    sent = [oracle.Observed(wire.Frame(can_id, 1, bytes([i])), 1000 + i, i, line=i + 1)
            for i, can_id in enumerate(sent_ids)]
    received = [oracle.Observed(sent[i].frame, 5000 + n, n, key="vehicle/can/rx") for n, i in enumerate(arrival)]
    bridge = {"rx_qos": table} if table else {}
    return SimpleNamespace(scenario=SimpleNamespace(expect={}, bridge=bridge),
                           buses=[SimpleNamespace(bus="vcan0", comparison=oracle.compare(sent, received))])


def test_ordering_is_judged_per_class_with_a_table():
    ids = [0x300, 0x301, 0x010, 0x302, 0x011]  # low, low, high, low, high
    overtaking = [2, 4, 0, 1, 3]  # the high class first, each class in bus order
    assert checks.ordering(run_result(EXAMPLE, ids, overtaking)) == []
    without = checks.ordering(run_result(None, ids, overtaking))  # one class: the same arrival is reordering
    assert without and "frames out of order" in without[0]
    within = checks.ordering(run_result(EXAMPLE, ids, [2, 4, 1, 0, 3]))  # 0x301 before 0x300: same class
    assert len(within) == 1 and "1 frames out of order" in within[0] and "judged per QoS class, 3 classes" in within[0]
    assert "300#" in within[0] and "301#" in within[0]  # the frame and the one of its class it arrived after
    # a table of one class (every rule equals the default) judges order as without one
    assert checks.ordering(run_result("0-7FF:data", ids, overtaking)) == without
