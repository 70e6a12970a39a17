"""Bad scenarios and traces stop with a clear file:line error (exit code 2)."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import cli, compose, scenario
from canbench.errors import ScenarioError, TraceError
from canbench.trace import read_trace

pytestmark = pytest.mark.unit

GOOD_TRACE = "(1700000000.000000) vcan0 123#DEADBEEF\n(1700000000.010000) vcan0 12345678#01\n"


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def scenario_text(**overrides) -> str:
    fields = {
        "name": "t", "duration_s": "5", "buses": "\n  - name: vcan0",
        "ecus": "\n  - name: engine\n    bus: vcan0\n    trace: trace.log", "expect": "\n  integrity: true",
    }
    fields.update(overrides)
    return "".join(f"{k}: {v}\n" for k, v in fields.items() if v is not None)


@pytest.mark.parametrize("text,line,fragment", [
    ("(1700000000.000000) vcan0 123#DEADBEEF\n(1700000000.1) vcan0 XYZ#00\n", 2, "not a candump -L frame"),
    ("(1700000000.000000) vcan0 123#DEADBEEF\n(1699999999.000000) vcan0 123#00\n", 2, "earlier than the line before"),
    ("(1700000000.000000) can7 123#00\n", 1, "interface 'can7'"),
    ("(1700000000.000000) vcan0 900#00\n", 1, "above 7FF"),
    ("(1700000000.000000) vcan0 123#000102030405060708\n", 1, "at most 8"),
])
def test_malformed_traces_name_the_line(tmp_path, text, line, fragment):
    path = write(tmp_path, "trace.log", text)
    with pytest.raises(TraceError) as err:
        read_trace(path, {"vcan0"})
    assert str(err.value).startswith(f"{path}:{line}: ") and fragment in str(err.value)


def test_empty_trace_is_refused(tmp_path):
    path = write(tmp_path, "trace.log", "# only a comment\n")
    with pytest.raises(TraceError, match="no frames"):
        read_trace(path)


def test_good_trace_keeps_line_numbers(tmp_path):
    path = write(tmp_path, "trace.log", "# recorded on the test track\n" + GOOD_TRACE)
    frames = read_trace(path, {"vcan0"})
    assert [f.line for f in frames] == [2, 3] and frames[1].message.is_extended_id


@pytest.mark.parametrize("overrides,line,fragment", [
    ({"duration_s": "'ten'"}, 2, "duration_s: 'ten' is not of type 'number'"),
    ({"duration_s": "-1"}, 2, "duration_s"),
    ({"colour": "blue"}, 11, "Additional properties are not allowed ('colour' was unexpected)"),
    ({"ecus": "\n  - name: engine\n    bus: vcan9\n    trace: trace.log"}, 7, "'vcan9' is not one of the buses"),
    ({"ecus": "\n  - name: engine\n    bus: vcan0\n    trace: missing.log"}, 8, "no such file"),
    ({"ecus": "\n  - name: engine\n    bus: vcan0\n    speed: 0\n    trace: trace.log"}, 8, "speed"),
    ({"expect": "\n  latency:\n    can_to_zenoh: {p50: 5}"}, 11, "'p50' was unexpected"),
    ({"ecus": "\n  - name: engine\n    bus: vcan0\n    trace: trace.log\n    sped: 2"}, 9, "'sped' was unexpected"),
    ({"ecus": "\n  - name: tester\n    bus: vcan0\n    role: echo"}, 6, "role echo needs echo_ids"),
    ({"ecus": "\n  - name: b\n    bus: vcan0\n    role: periodic\n    run_s: 1"}, 6, "role periodic needs messages"),
    ({"ecus": "\n  - name: b\n    bus: vcan0\n    role: periodic\n    run_s: 1\n    messages:\n"
              "      - {id: '12G', cycle_ms: 10}"}, 11, "'12G' does not match"),
    ({"commands": "\n  - bus: vcan3\n    trace: trace.log"}, 12, "commands.0.bus: 'vcan3' is not one of"),
    ({"commands": "\n  - bus: vcan0\n    messages: [{id: '600', cycle_ms: 10}]"}, 12, "messages need run_s"),
    ({"commands": "\n  - bus: vcan0"}, 12, "give either trace or messages"),
    ({"topology": "\n  consumer: bridge"}, 12, "only in bridge.mode peer or router"),
    ({"expect": "\n  cycle_time: {tolerance_pct: -5}"}, 10, "cycle_time.tolerance_pct"),
    ({"faults": "\n  - {at_s: 1, action: router_restart, id: '7F0'}"}, 12, "belong to can_flood only"),
    ({"faults": "\n  - {at_s: 1, action: can_flood, bus: vcan7}"}, 12, "'vcan7' is not one of the buses"),
    ({"faults": "\n  - {at_s: 1, action: partition, duration_s: 5, every_s: 5}"}, 12, "longer than duration_s"),
    ({"faults": "\n  - {at_s: 1, action: unplug}"}, 12, "'unplug' is not one of"),
    ({"commands": "\n  - bus: vcan0\n    run_s: 1\n    messages: [{id: '7F0', cycle_ms: 10}]",
      "faults": "\n  - {at_s: 1, action: can_flood}"}, 16, "can_flood id 7F0 is sent by an ECU or a command too"),
])
def test_bad_scenarios_name_file_line_and_field(tmp_path, overrides, line, fragment):
    write(tmp_path, "trace.log", GOOD_TRACE)
    path = write(tmp_path, "s.yaml", scenario_text(**overrides))
    with pytest.raises(ScenarioError) as err:
        scenario.load(path)
    assert str(err.value).startswith(f"{path}:{line}: "), (str(err.value), path.read_text())
    assert fragment in str(err.value)


def test_not_yaml_and_not_a_mapping(tmp_path):
    with pytest.raises(ScenarioError, match=":2: not valid YAML"):
        scenario.load(write(tmp_path, "a.yaml", "name: x\n  bad: : indent\n"))
    with pytest.raises(ScenarioError, match="is a mapping"):
        scenario.load(write(tmp_path, "b.yaml", "- just\n- a list\n"))


def test_cli_exit_code_2_and_one_line(tmp_path, capsys):
    write(tmp_path, "trace.log", GOOD_TRACE)
    path = write(tmp_path, "s.yaml", scenario_text(duration_s="'ten'"))
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith(f"{path}:2: ") and err[1].startswith("canbench validate: 1 problem")


def test_repeated_fault_steps_expand_until_their_end(tmp_path):
    write(tmp_path, "trace.log", GOOD_TRACE)
    path = write(tmp_path, "s.yaml", scenario_text(duration_s="100", faults=(
        "\n  - {at_s: 10, action: router_restart, every_s: 30}"
        "\n  - {at_s: 5, action: can_flood, duration_s: 2, id: '123', max_frames: 50}")))
    sc = scenario.load(path)
    assert [(f.at_s, f.action) for f in sc.faults] == [(10, "router_restart"), (40, "router_restart"),
                                                       (70, "router_restart"), (100, "router_restart"),
                                                       (5, "can_flood")]
    flood = sc.faults[-1]
    assert (flood.bus, flood.can_id, flood.max_frames, flood.duration_s) == ("vcan0", 0x123, 50, 2)


def test_partition_gives_the_bridge_its_own_router_listener(tmp_path):
    write(tmp_path, "trace.log", GOOD_TRACE)
    path = write(tmp_path, "s.yaml", scenario_text(faults="\n  - {at_s: 1, action: partition, duration_s: 2}"))
    services = compose.compose_override(scenario.load(path), "/scenarios/s.yaml")["services"]
    # the scheme: tls by default, tcp with BENCH_ACCESS=open (compose interpolates it)
    assert "${BENCH_ZENOH_SCHEME:-tls}/0.0.0.0:7446" in services["router"]["command"]
    assert services["bridge"]["environment"]["ZENOH_ROUTER_ADDRESS"] == "${BENCH_ZENOH_SCHEME:-tls}/router:7446"
    assert services["orchestrator"]["volumes"] == ["/var/run/docker.sock:/var/run/docker.sock"]


def test_shipped_scenarios_are_valid():
    for path in sorted(Path(__file__).resolve().parents[2].glob("scenarios/**/*.yaml")):
        assert cli.main(["validate", str(path)]) == 0


def test_an_alias_bomb_is_refused_at_once(tmp_path, capsys):
    # nine aliases of nine ... of a list: 387 million values read through (a minute and 6 GiB before)
    levels = ["  - &a0 [x, x, x, x, x, x, x, x, x]"] + [
        f"  - &a{n} [{', '.join([f'*a{n - 1}'] * 9)}]" for n in range(1, 9)]
    path = write(tmp_path, "s.yaml", scenario_text(ecus="\n" + "\n".join(levels)))
    write(tmp_path, "trace.log", GOOD_TRACE)
    with pytest.raises(ScenarioError, match=r"s.yaml: more than 1000000 values once its aliases \(\*name\) are "
                                            r"expanded"):
        scenario.load(path)
    # aliases a scenario really uses (shared settings) are read as ever
    shared = "\n  - &engine\n    name: engine\n    bus: vcan0\n    trace: trace.log\n  - <<: *engine\n    name: body"
    path = write(tmp_path, "s.yaml", scenario_text(ecus=shared))
    assert [e.name for e in scenario.load(path).ecus] == ["engine", "body"]


def test_a_long_value_in_a_problem_is_cut_to_its_reason(tmp_path, capsys):
    path = write(tmp_path, "s.yaml", scenario_text(ecus="\n  - [" + ", ".join(["x"] * 5000) + "]"))
    write(tmp_path, "trace.log", GOOD_TRACE)
    assert cli.main(["validate", str(path)]) == 2
    said = capsys.readouterr().err.splitlines()[0]
    assert len(said) < 400 and said.startswith(f"{path}:6: ecus.0: ['x', 'x'") and " ... " in said
    assert said.endswith("'x', 'x'] is not of type 'object'")


def test_a_large_scenario_is_not_blamed_on_aliases():
    shared = [0] * 1000
    assert scenario._values_over({"a": [shared] * 2000}, scenario.MAX_VALUES)  # 2 million values read through
    assert not scenario._values_over({"a": [shared] * 2000}, scenario.MAX_VALUES, each_once=True)  # 1 001 written
    assert scenario._values_over({"a": list(range(1_000_001))}, scenario.MAX_VALUES, each_once=True)
