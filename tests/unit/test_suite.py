"""make test's suite logic (canbench.suite): shards balanced by expected duration and the same
on every runner, and one summary (index.html, merged junit.xml, summary.json, exit code)."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from canbench import cli, suite
from canbench.errors import InputError

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]


def test_shards_cover_every_scenario_once_and_balance():
    expected = {f"s{i}.yaml": float(d) for i, d in enumerate([70, 60, 60, 50, 40, 30, 30, 30, 30, 30, 20])}
    for n in range(1, 5):
        shares = suite.shards(expected, n)
        names = [s for share in shares for s in share]
        assert sorted(names) == sorted(expected)  # each exactly once
        totals = [sum(expected[s] for s in share) for share in shares]
        # greedy longest-first: no share exceeds the mean by more than the longest single scenario
        assert max(totals) - sum(totals) / n <= max(expected.values())
        assert shares == suite.shards(dict(reversed(list(expected.items()))), n)  # input order is irrelevant
    a, b = (sum(expected[s] for s in share) for share in suite.shards(expected, 2))
    assert abs(a - b) <= min(expected.values())  # 220 / 230 of 450


def test_plan_of_the_shipped_scenarios(capsys):
    paths = sorted(str(p.relative_to(REPO)) for p in (REPO / "scenarios").glob("*.yaml"))
    halves = [suite.plan(paths, f"{k}/2") for k in (1, 2)]
    assert sorted(p for half in halves for _, p in half) == paths
    assert abs(sum(s for s, _ in halves[0]) - sum(s for s, _ in halves[1])) <= max(s for s, _ in suite.plan(paths))
    for half in halves:
        assert [s for s, _ in half] == sorted((s for s, _ in half), reverse=True)  # longest first
    assert suite.expected_s(REPO / "scenarios" / "smoke.yaml") == suite.SETUP_S + 10


@pytest.mark.parametrize("text", ["3/2", "0/2", "1", "a/b"])
def test_bad_shard_is_input_error(text):
    with pytest.raises(InputError, match="SHARD"):
        suite.plan(["x.yaml"], text)


JUNIT = """<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest" errors="0" failures="{f}"
 skipped="1" tests="3" time="1.0"><testcase classname="tests.scenarios.test_scenario" name="test_check[integrity]"
 time="0.1">{failure}</testcase><testcase classname="tests.scenarios.test_scenario" name="test_check[ordering]"
 time="0.1"/><testcase classname="tests.scenarios.test_scenario" name="test_check[round_trip]" time="0">
 <skipped message="not asked for"/></testcase></testsuite></testsuites>"""


def make_suite(tmp_path: Path, runs: list[tuple[str, str, int]]) -> Path:
    reports = tmp_path / "reports"
    suite_dir = reports / "suite-x"
    suite_dir.mkdir(parents=True)
    (suite_dir / "plan.tsv").write_text("".join(f"40\t{s}\n" for s, _, _ in runs) + "30\tscenarios/late.yaml\n")
    lines = []
    for s, run_id, code in runs:
        if run_id != "-":
            (reports / run_id).mkdir()
            failed = code == 1
            (reports / run_id / "junit.xml").write_text(JUNIT.format(
                f=int(failed), failure='<failure message="3 frames lost"/>' if failed else ""))
        lines.append(f"{s}\t{run_id}\t{code}\t33\n")
    (suite_dir / "runs.tsv").write_text("".join(lines))
    return suite_dir


def test_summary_merges_every_run(tmp_path):
    suite_dir = make_suite(tmp_path, [("scenarios/smoke.yaml", "r1-smoke", 0), ("scenarios/burst.yaml", "r2-burst", 1),
                                      ("bad/x.yaml", "-", 2)])
    assert cli.main(["suite", "summary", str(suite_dir)]) == 1
    summary = json.loads((suite_dir / "summary.json").read_text())
    assert [(r["scenario"], r["verdict"]) for r in summary["runs"]] == [
        ("scenarios/smoke.yaml", "passed"), ("scenarios/burst.yaml", "failed"), ("bad/x.yaml", "invalid scenario"),
        ("scenarios/late.yaml", "not run")]
    assert summary["runs"][1]["checks"]["test_check[integrity]"] == "failed" and not summary["passed"]
    root = ET.parse(suite_dir / "junit.xml").getroot()
    assert [ts.get("name") for ts in root] == ["smoke", "burst", "x", "late"]
    # 3 checks + the run itself for each run with a junit.xml, the run alone otherwise
    assert (root.get("tests"), root.get("failures"), root.get("skipped")) == ("10", "4", "2")
    case = root.find("testsuite/testcase")
    assert case is not None and case.get("classname") == "smoke.tests.scenarios.test_scenario"
    page = (suite_dir / "index.html").read_text()
    assert '<a href="../r1-smoke/report.html">' in page and '<a href="../r2-burst/report.html">' in page
    assert "1 of 4 scenarios passed; exit code 1" in page


@pytest.mark.parametrize("codes,expected", [((0, 0), 0), ((0, 2), 2), ((2, 1), 1)])
def test_suite_exit_code(codes, expected):
    runs = [suite.Run(f"s{i}", None if c == 2 else f"r{i}", c, 1) for i, c in enumerate(codes)]
    assert suite.exit_code(runs) == expected


def metrics(p50: float, lost: int = 0) -> dict:
    summary = {"sent": 100, "matched": 100 - lost, "lost": lost, "duplicates": 0, "corrupted": 0, "reordered": 0,
               "latency": {"count": 100, "p50_ms": p50, "p90_ms": p50, "p99_ms": p50, "max_ms": p50}}
    return {"schema_version": 1, "run_id": "r", "scenario": "s", "can_to_zenoh": {"vcan0": summary},
            "verdicts": {"test_check[integrity]": "passed" if not lost else "failed"}}


def write_suite(reports: Path, suite_name: str, runs: dict[str, tuple[dict, int]]) -> None:
    (reports / suite_name).mkdir(parents=True)
    entries = []
    for name, (m, code) in runs.items():
        run_id = f"2026-{suite_name}-{name}"
        (reports / run_id).mkdir()
        (reports / run_id / "metrics.json").write_text(json.dumps(m))
        entries.append({"scenario": f"scenarios/{name}.yaml", "run_id": run_id, "exit_code": code})
    (reports / suite_name / "summary.json").write_text(json.dumps({"runs": entries}))


def test_suite_compare_against_the_last_good_night(tmp_path, capsys):
    old, new = tmp_path / "old", tmp_path / "new"
    # two shards' downloads side by side; the baseline's failed run is no baseline
    write_suite(old, "suite-a", {"smoke": (metrics(0.5), 0), "burst": (metrics(0.5), 0)})
    write_suite(old, "suite-b", {"peer": (metrics(0.5, lost=3), 1)})
    write_suite(new, "suite-c", {"smoke": (metrics(0.5), 0), "burst": (metrics(0.5), 0)})
    write_suite(new, "suite-d", {"peer": (metrics(0.5), 0)})
    assert cli.main(["suite", "compare", str(old), str(new)]) == 0
    out = capsys.readouterr().out
    assert "peer: no baseline" in out and "suite compare: 0 of 3 scenarios regressed" in out
    write_suite(new, "suite-e", {"burst": (metrics(1.5), 0)})  # newer run of burst: p50 x3
    assert cli.main(["suite", "compare", str(old), str(new)]) == 1
    assert "suite compare: 1 of 3 scenarios regressed: burst" in capsys.readouterr().out


def test_suite_compare_fails_a_scenario_whose_run_left_no_metrics(tmp_path, capsys):
    old, new = tmp_path / "old", tmp_path / "new"
    write_suite(old, "suite-a", {"smoke": (metrics(0.5), 0), "burst": (metrics(0.5), 0), "peer": (metrics(0.5), 0)})
    write_suite(new, "suite-b", {"smoke": (metrics(0.5), 0)})
    # burst ran and ended in a bench error before its metrics: listed, no run directory
    summary = new / "suite-b" / "summary.json"
    runs = json.loads(summary.read_text())["runs"] + [{"scenario": "scenarios/burst.yaml", "run_id": None,
                                                       "exit_code": 1}]
    summary.write_text(json.dumps({"runs": runs}))
    assert cli.main(["suite", "compare", str(old), str(new)]) == 1
    out = capsys.readouterr().out
    assert "burst: its run in" in out and "left no metrics.json" in out
    assert "peer: not in the suites under" in out  # only the baseline has it: named, not a failure
    assert "suite compare: 0 of 1 scenarios regressed; 1 left no metrics: burst" in out



def test_suite_compare_passes_what_a_device_of_your_own_did_not_run(tmp_path, capsys):
    old, new = tmp_path / "old", tmp_path / "new"
    write_suite(old, "suite-a", {"smoke": (metrics(0.5), 0), "router-faults": (metrics(0.5), 0)})
    write_suite(new, "suite-b", {"smoke": (metrics(0.5), 0)})
    summary = new / "suite-b" / "summary.json"
    runs = json.loads(summary.read_text())["runs"] + [{"scenario": "scenarios/router-faults.yaml", "run_id": None,
                                                       "exit_code": 0, "left_out": "fault steps ..."}]
    summary.write_text(json.dumps({"runs": runs}))
    assert cli.main(["suite", "compare", str(old), str(new)]) == 0
    assert "left no metrics" not in capsys.readouterr().out


def write_verdicts(d: Path, runs: dict[str, dict[str, str]]) -> Path:
    d.mkdir(parents=True)
    entries = [{"scenario": f"scenarios/{n}.yaml", "verdict": "passed", "checks": c} for n, c in runs.items()]
    (d / "summary.json").write_text(json.dumps({"runs": entries}))
    return d


def test_suite_same_serial_against_shards(tmp_path, capsys):
    ok = {"test_check[integrity]": "passed", "test_check[recovery]": "skipped"}
    serial = write_verdicts(tmp_path / "serial", {"smoke": ok, "burst": ok, "peer": ok})
    shard1 = write_verdicts(tmp_path / "s1", {"smoke": ok, "peer": ok})
    shard2 = write_verdicts(tmp_path / "s2", {"burst": ok})
    assert cli.main(["suite", "same", str(serial), "--as", str(shard1), str(shard2)]) == 0
    assert "3 scenarios compared, 0 differences" in capsys.readouterr().out
    # one check's verdict differs, one scenario missing: both named
    shard2b = write_verdicts(tmp_path / "s2b", {"burst": {**ok, "test_check[integrity]": "failed"}})
    assert cli.main(["suite", "same", str(serial), "--as", str(shard2b)]) == 1
    out = capsys.readouterr().out
    assert "burst: test_check[integrity] passed -> failed" in out
    assert "peer: only in the first" in out and "smoke: only in the first" in out
    # a scenario in two suites of one side is an error, not a silent pick
    with pytest.raises(InputError, match="more than one"):
        suite.same_verdicts([serial, shard1], [shard2])


def test_a_runs_junit_cut_short_fails_that_run_not_the_summary(tmp_path):
    # pytest killed while writing it (or a full disk): the summary raised and the suite had no junit.xml at all
    suite_dir = make_suite(tmp_path, [("scenarios/smoke.yaml", "r1-smoke", 0), ("scenarios/burst.yaml", "r2-burst", 0)])
    junit = suite_dir.parent / "r2-burst" / "junit.xml"
    junit.write_text(junit.read_text()[:150])
    assert cli.main(["suite", "summary", str(suite_dir)]) == 1
    root = ET.parse(suite_dir / "junit.xml").getroot()
    burst = next(ts for ts in root if ts.get("name") == "burst")
    failure = burst.find("testcase[@name='bench_run']/failure")
    assert failure is not None and "r2-burst/junit.xml: not JUnit XML" in failure.get("message", "")
    assert json.loads((suite_dir / "summary.json").read_text())["runs"][1]["checks"]["bench_run"] == "failed"


def test_a_merged_suites_time_holds_its_run(tmp_path):
    # Jenkins takes a suite's duration from its time: pytest's 1.0 s, the run's 33 s
    suite_dir = make_suite(tmp_path, [("scenarios/smoke.yaml", "r1-smoke", 0)])
    cli.main(["suite", "summary", str(suite_dir)])
    root = ET.parse(suite_dir / "junit.xml").getroot()
    smoke = next(ts for ts in root if ts.get("name") == "smoke")
    assert float(smoke.get("time", "0")) == 33  # the run's wall time, its checks' within it
    assert float(root.get("time", "0")) == sum(float(ts.get("time", "0")) for ts in root)
