"""`canbench suite`: the scenarios of one `make test` as a suite (scripts/bench-suite).

  canbench suite plan [--shard K/N] SCENARIO...   the share of runner K of N, longest first:
                                                  one "<expected s>\\t<scenario>" line each
  canbench suite summary SUITE_DIR                index.html, junit.xml and summary.json of the
                                                  runs listed in SUITE_DIR/runs.tsv; exit code
                                                  of the suite
  canbench suite compare OLD_REPORTS NEW_REPORTS  `canbench compare` of every scenario run in the
                                                  suites under NEW against its passed run in OLD
                                                  (nightly CI: OLD is the last good night's)
  canbench suite same SUITE_DIR... --as SUITE_DIR...
                                                  the verdict of every check of every scenario in
                                                  the first suites equals the second's (a serial
                                                  run against JOBS=N, or against its shards)

Shards are balanced by expected duration (longest first onto the least loaded shard) and
depend only on the scenario files, so n runners given the same files split them exactly,
each scenario on one runner."""
from __future__ import annotations

import argparse
import html
import json
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass, field
from pathlib import Path

from . import compare, device, scenario
from .errors import InputError, ScenarioError

DEVICE_REFUSED = 4  # plan's exit code: DEVICE is not host:PORT, or no scenario is left (not argparse's 2)
# A run's fixed cost on top of its traffic phase (compose up, readiness, analysis, reports,
# down): measured 15-25 s for the shipped scenarios on 2 cores.
SETUP_S = 20.0


def expected_s(path: Path) -> float:
    """What a run of the scenario is expected to take; only the file decides (shards must agree)."""
    try:
        duration = scenario.parse(path).get("duration_s", 0)
    except ScenarioError:
        duration = 0
    return SETUP_S + (float(duration) if isinstance(duration, int | float) else 0.0)


def parse_shard(text: str) -> tuple[int, int]:
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise InputError("SHARD", None, f"{text!r} is not K/N (e.g. 1/2)") from None
    if not 1 <= k <= n:
        raise InputError("SHARD", None, f"{text!r}: K must be 1..N")
    return k, n


def shards(expected: dict[str, float], n: int) -> list[list[str]]:
    """n shares of the scenarios with totals as even as greedy allows; each share longest first.
    Ties are broken by name, so the split is the same on every runner."""
    shares: list[list[str]] = [[] for _ in range(n)]
    totals = [0.0] * n
    for name in sorted(expected, key=lambda s: (-expected[s], s)):
        i = min(range(n), key=lambda j: (totals[j], j))
        shares[i].append(name)
        totals[i] += expected[name]
    return shares


def plan(paths: list[str], shard: str | None = None) -> list[tuple[float, str]]:
    expected = {p: expected_s(Path(p)) for p in dict.fromkeys(paths)}
    k, n = parse_shard(shard) if shard else (1, 1)
    return [(expected[p], p) for p in shards(expected, n)[k - 1]]


LEFT_OUT = "left-out"  # a plan line's first field for a scenario the device cannot run: left-out<TAB>path<TAB>why


def for_device(spec: str, paths: list[str], can_mode: str, restartable: bool = False) \
        -> tuple[list[str], dict[str, str]]:
    """The scenarios a device of your own can run, and why each other one is left out (also said
    on stderr). ValueError: a DEVICE that is not host:PORT, or no scenario left."""
    device.parse(spec)
    kept, left_out = [], {}
    for path in paths:
        why = device.refusals(scenario.load(Path(path)), can_mode, restartable)
        if why:
            left_out[path] = "; ".join(why)
            print(f"suite: not run against DEVICE={spec}: {left_out[path]}", file=sys.stderr)
        else:
            kept.append(path)
    if not kept:
        raise ValueError(f"DEVICE={spec}: none of the {len(paths)} scenario(s) can run against a device of your own")
    return kept, left_out


@dataclass
class Run:
    scenario: str
    run_id: str | None  # None: bench-run stopped before a run existed (invalid scenario)
    exit_code: int
    seconds: int
    expected_s: float = 0.0
    verdict: str = ""
    checks: dict[str, str] = field(default_factory=dict)
    left_out: str = ""  # why a device of your own did not run it (then it never ran, and failed nothing)


def read_runs(suite_dir: Path) -> list[Run]:
    expected = {}
    runs = []
    if (suite_dir / "plan.tsv").exists():
        for line in (suite_dir / "plan.tsv").read_text().splitlines():
            seconds, path = line.split("\t", 1)
            if seconds == LEFT_OUT:
                path, why = path.split("\t", 1)
                runs.append(Run(path, None, 0, 0, verdict=f"not run against the device: {why}", left_out=why))
            else:
                expected[path] = float(seconds)
    tsv = suite_dir / "runs.tsv"
    for line in tsv.read_text().splitlines() if tsv.exists() else []:
        path, run_id, code, seconds = line.split("\t")
        runs.append(Run(path, None if run_id == "-" else run_id, int(code), int(seconds), expected.get(path, 0.0)))
    # scenarios that never reported (the suite was interrupted) count as failed
    for path in expected.keys() - {r.scenario for r in runs}:
        runs.append(Run(path, None, 1, 0, expected[path], "not run"))
    order = list(expected)
    runs.sort(key=lambda r: (order.index(r.scenario) if r.scenario in order else len(order), r.scenario))
    return runs


def _case_outcome(case: ET.Element) -> str:
    if case.find("failure") is not None or case.find("error") is not None:
        return "failed"
    return "skipped" if case.find("skipped") is not None else "passed"


def merged_junit(runs: list[Run], reports: Path, suite: str) -> ET.Element:
    root = ET.Element("testsuites", name=suite)
    for r in runs:
        name = Path(r.scenario).stem
        junit = reports / r.run_id / "junit.xml" if r.run_id else None
        suites = []
        unreadable = None  # a run's junit.xml cut short (its pytest killed while writing, a full disk)
        if junit is not None and junit.exists():
            try:
                parsed = ET.parse(junit).getroot()
                suites = [parsed] if parsed.tag == "testsuite" else list(parsed.iter("testsuite"))
            except ET.ParseError as e:
                unreadable = f"{junit}: not JUnit XML ({e}): its checks are unknown"
        if not suites:
            suites = [ET.Element("testsuite", tests="0", failures="0", errors="0", skipped="0", time="0")]
        for ts in suites:
            ts.set("name", name)
            for case in ts.iter("testcase"):
                case.set("classname", f"{name}.{case.get('classname', '')}".rstrip("."))
                r.checks[case.get("name", "?")] = _case_outcome(case)
            # the run as a whole: an ECU that crashed or a run that never started fails here too
            run_case = ET.SubElement(ts, "testcase", classname=name, name="bench_run", time=str(r.seconds))
            if r.left_out:
                ET.SubElement(run_case, "skipped", message=f"{r.scenario}: {r.verdict}")
            elif r.exit_code != 0 or unreadable:
                ET.SubElement(run_case, "failure", message=f"{r.scenario}: {r.verdict} (exit {r.exit_code})"
                              + (f"; {unreadable}" if unreadable else ""))
                r.checks["bench_run"] = "failed"
            cases = list(ts.iter("testcase"))
            # the run's time: Jenkins takes a suite's duration from it, GitLab adds up the cases
            ts.set("time", f"{max(float(ts.get('time') or 0), r.seconds):g}")
            ts.set("tests", str(len(cases)))
            ts.set("failures", str(sum(c.find("failure") is not None for c in cases)))
            ts.set("errors", str(sum(c.find("error") is not None for c in cases)))
            ts.set("skipped", str(sum(c.find("skipped") is not None for c in cases)))
            root.append(ts)
    for key in ("tests", "failures", "errors", "skipped"):
        root.set(key, str(sum(int(ts.get(key, "0")) for ts in root)))
    root.set("time", f"{sum(float(ts.get('time') or 0) for ts in root):g}")
    return root


def verdict(code: int, run_id: str | None) -> str:
    if code == 0:
        return "passed"
    if code == 2 and run_id is None:
        return "invalid scenario"
    return "failed" if run_id else "bench error"


def exit_code(runs: list[Run]) -> int:
    codes = {r.exit_code for r in runs}
    return 0 if codes <= {0} else 2 if codes <= {0, 2} else 1


def index_html(runs: list[Run], suite: str, code: int) -> str:
    rows = []
    for r in runs:
        link = (f'<a href="../{html.escape(r.run_id)}/report.html">{html.escape(r.run_id)}</a>'
                if r.run_id else "-")
        failed = [c for c, o in r.checks.items() if o == "failed" and c != "bench_run"]
        rows.append(f"<tr class={'ok' if r.exit_code == 0 else 'bad'}><td>{html.escape(r.scenario)}</td>"
                    f"<td>{html.escape(r.verdict)}</td><td>{r.seconds} s</td><td>~{r.expected_s:.0f} s</td>"
                    f"<td>{link}</td><td>{html.escape(', '.join(failed))}</td></tr>")
    passed = sum(r.exit_code == 0 and not r.left_out for r in runs)
    left_out = sum(bool(r.left_out) for r in runs)
    return ("<!doctype html><meta charset=utf-8><title>" + html.escape(suite) + "</title>"
            "<style>body{font-family:sans-serif}td,th{padding:2px 8px;text-align:left}"
            ".ok td:nth-child(2){color:#070}.bad td:nth-child(2){color:#b00}</style>"
            f"<h1>{html.escape(suite)}</h1><p>{passed} of {len(runs) - left_out} scenarios passed"
            + (f" ({left_out} not run against the device)" if left_out else "") + f"; exit code {code}; "
            "<a href=junit.xml>junit.xml</a>, <a href=summary.json>summary.json</a></p>"
            "<table><tr><th>scenario</th><th>verdict</th><th>took</th><th>expected</th><th>run</th>"
            "<th>failed checks</th></tr>" + "".join(rows) + "</table>\n")


def summarise(suite_dir: Path) -> int:
    """Write the suite's index.html, junit.xml and summary.json; its exit code."""
    runs = read_runs(suite_dir)
    for r in runs:
        r.verdict = r.verdict or verdict(r.exit_code, r.run_id)
    junit = merged_junit(runs, suite_dir.parent, suite_dir.name)
    code = exit_code(runs)
    ET.ElementTree(junit).write(suite_dir / "junit.xml", encoding="utf-8", xml_declaration=True)
    (suite_dir / "index.html").write_text(index_html(runs, suite_dir.name, code))
    summary = {"schema_version": 1, "suite": suite_dir.name, "shard": os.environ.get("SHARD") or "1/1",
               "jobs": int(os.environ.get("JOBS") or 1), "passed": code == 0, "exit_code": code,
               "runs": [asdict(r) for r in runs]}
    (suite_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return code


def suite_runs(reports: Path, passed_only: bool = False) -> dict[str, Path]:
    """scenario name -> run directory, for every run of the suites under reports (several shards'
    downloads side by side); the newest run of a name wins."""
    runs: dict[str, tuple[str, Path]] = {}
    for summary in sorted(reports.glob("**/summary.json")):
        for r in json.loads(summary.read_text()).get("runs", []):
            run_dir = summary.parent.parent / r["run_id"] if r.get("run_id") else None
            if passed_only and r.get("exit_code") != 0:
                continue
            if run_dir is not None and (run_dir / "metrics.json").exists():
                name = Path(r["scenario"]).stem
                if name not in runs or runs[name][0] < r["run_id"]:
                    runs[name] = (r["run_id"], run_dir)
    return {name: run_dir for name, (_, run_dir) in runs.items()}


def listed_scenarios(reports: Path) -> set[str]:
    """Every scenario the suites under reports ran, whether or not its run left a metrics.json (not
    those a device of your own left out: they never ran)."""
    return {Path(r["scenario"]).stem for summary in reports.glob("**/summary.json")
            for r in json.loads(summary.read_text()).get("runs", []) if r.get("scenario") and not r.get("left_out")}


def compare_suites(old_reports: Path, new_reports: Path) -> int:
    """Exit 1 if any scenario regressed against its baseline, or ran tonight and left no metrics to
    compare (a bench error, a run stopped early); a scenario without a baseline is named, and so is
    one only the baseline has (removed since, or its shard's reports are missing)."""
    old, new = suite_runs(old_reports, passed_only=True), suite_runs(new_reports)
    if not new:
        raise InputError(str(new_reports), None, "no suite summary.json with runs under it (make test writes them)")
    no_metrics = sorted(listed_scenarios(new_reports) - set(new))
    for name in no_metrics:
        print(f"{name}: its run in {new_reports} left no metrics.json: nothing to compare (a failure)")
    for name in sorted(set(old) - set(new) - set(no_metrics)):
        print(f"{name}: not in the suites under {new_reports} (removed, or its shard's reports are missing)")
    regressed = []
    for name, run_dir in sorted(new.items()):
        if name not in old:
            print(f"{name}: no baseline in {old_reports} (a first good run becomes one)")
            continue
        a, b = compare.load_metrics(old[name]), compare.load_metrics(run_dir)
        rows = compare.compare(a, b)
        print(f"{name}: {old[name].name} -> {run_dir.name}\n{compare.render(rows, a, b)}")
        if any(r.regression for r in rows):
            regressed.append(name)
    print(f"suite compare: {len(regressed)} of {len(new)} scenarios regressed{': ' if regressed else ''}"
          f"{', '.join(regressed)}" + (f"; {len(no_metrics)} left no metrics: {', '.join(no_metrics)}"
                                       if no_metrics else ""))
    return 1 if regressed or no_metrics else 0


def check_verdicts(suite_dirs: list[Path]) -> dict[str, dict[str, str]]:
    """scenario name -> {check: passed/failed/skipped} over the suites' summary.json files."""
    verdicts: dict[str, dict[str, str]] = {}
    for d in suite_dirs:
        summary = d / "summary.json"
        if not summary.is_file():
            raise InputError(str(d), None, "no summary.json (a suite directory that make test wrote)")
        for r in json.loads(summary.read_text()).get("runs", []):
            name = Path(r["scenario"]).stem
            if name in verdicts:
                raise InputError(str(d), None, f"{name} is in more than one of these suites")
            verdicts[name] = {**r.get("checks", {}), "(run)": r.get("verdict", "?")}
    return verdicts


def same_verdicts(a_dirs: list[Path], b_dirs: list[Path]) -> int:
    """Exit 1 unless both sides ran the same scenarios with the same verdict for every check."""
    a, b = check_verdicts(a_dirs), check_verdicts(b_dirs)
    differences = [f"{name}: only in {'the first' if name in a else 'the second'}" for name in sorted(set(a) ^ set(b))]
    for name in sorted(set(a) & set(b)):
        for check in sorted(set(a[name]) | set(b[name])):
            va, vb = a[name].get(check, "absent"), b[name].get(check, "absent")
            if va != vb:
                differences.append(f"{name}: {check} {va} -> {vb}")
    print("\n".join(differences))
    print(f"suite same: {len(set(a) & set(b))} scenarios compared, {len(differences)} differences")
    return 1 if differences else 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="suite_cmd", required=True)
    q = sub.add_parser("plan", help="the scenarios of one shard, longest first, with expected seconds")
    q.add_argument("scenarios", nargs="+")
    q.add_argument("--shard", help="K/N: the K-th of N balanced shares (default: all)")
    q.add_argument("--device", help="host:PORT: leave out, saying why, the scenarios a device of your own "
                                    "cannot stand in for (canbench.device)")
    q.add_argument("--can-mode", choices=("userspace", "kernel"), default="userspace")
    q.add_argument("--device-restartable", action="store_true",
                   help="bench-run can stop the device and start it again (DEVICE_CMD or DEVICE_HOOK)")
    q = sub.add_parser("summary", help="index.html, junit.xml and summary.json of a suite's runs")
    q.add_argument("suite_dir", type=Path)
    q = sub.add_parser("compare", help="canbench compare of every scenario against the baseline suites")
    q.add_argument("old_reports", type=Path, help="reports of the last good run (their suite summary.json)")
    q.add_argument("new_reports", type=Path, help="reports of this run")
    q = sub.add_parser("same", help="every check's verdict of every scenario equal in two sets of suites")
    q.add_argument("suites", type=Path, nargs="+", help="suite directories (reports/suite-...)")
    q.add_argument("--as", dest="other", type=Path, nargs="+", required=True, help="the suites to compare with")


def main(args: argparse.Namespace) -> int:
    if args.suite_cmd == "plan":
        scenarios = args.scenarios
        left_out: dict[str, str] = {}
        if args.device:
            try:
                scenarios, left_out = for_device(args.device, scenarios, args.can_mode, args.device_restartable)
            except ValueError as e:
                print(f"suite: {e}", file=sys.stderr)
                return DEVICE_REFUSED
        for seconds, path in plan(scenarios, args.shard):
            print(f"{seconds:.0f}\t{path}")
        if not args.shard or parse_shard(args.shard)[0] == 1:  # said once across the shards: by the first
            for path, why in left_out.items():
                print(f"{LEFT_OUT}\t{path}\t{why}")
        return 0
    if args.suite_cmd == "compare":
        return compare_suites(args.old_reports, args.new_reports)
    if args.suite_cmd == "same":
        return same_verdicts(args.suites, args.other)
    code = summarise(args.suite_dir)
    print(f"suite: {args.suite_dir}/index.html", file=sys.stderr)
    return code
