"""canbench compare OLD NEW: diff two runs' metrics.json with noise-aware
thresholds, the nightly job's gate. A regression is

  - a check that passed in OLD and fails in NEW;
  - more frames lost, duplicated, corrupted or reordered in any direction;
  - a median latency above OLD's by more than --latency-pct percent AND by
    more than --floor-ms (tiny absolute changes are scheduler noise);
    p99 and max are shown, gated only with --p99-pct (tails are noisy).

Exit code 1 on a regression, 0 otherwise, 2 when the files cannot be compared."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError

DIRECTIONS = ("can_to_zenoh", "zenoh_to_can", "round_trip")
COUNTS = ("lost", "duplicates", "corrupted", "reordered")
SUPPORTED_SCHEMA = 1


@dataclass
class Row:
    what: str
    old: str
    new: str
    regression: bool
    note: str = ""


def load_metrics(path: Path) -> dict:
    file = path / "metrics.json" if path.is_dir() else path
    try:
        metrics = json.loads(file.read_text())
    except (OSError, ValueError) as e:
        raise InputError(str(file), None, f"not a readable metrics.json: {e}") from None
    if not isinstance(metrics, dict):
        raise InputError(str(file), None, f"not a run's metrics.json: a JSON {type(metrics).__name__}, not an object")
    if metrics.get("schema_version") != SUPPORTED_SCHEMA:
        raise InputError(str(file), None, f"schema_version {metrics.get('schema_version')!r}, this canbench reads "
                         f"{SUPPORTED_SCHEMA}")
    return metrics


def compare(old: dict, new: dict, latency_pct: float = 50.0, floor_ms: float = 0.05,
            p99_pct: float | None = None) -> list[Row]:
    rows: list[Row] = []
    if old.get("verdicts") and not new.get("verdicts"):  # the run stopped between its analysis and its checks
        rows.append(Row("verdicts", f"{len(old['verdicts'])} checks", "none", True, "no check ran"))
    for test, before in sorted(old.get("verdicts", {}).items()):
        after = new.get("verdicts", {}).get(test, "missing")
        if before != after:
            rows.append(Row(test, before, after, before == "passed" and after == "failed"))
    for direction in DIRECTIONS:
        for bus, after in sorted(new.get(direction, {}).items()):
            before = old.get(direction, {}).get(bus)
            if before is None:
                rows.append(Row(f"{direction} {bus}", "-", "new", False, "not in the old run"))
                continue
            for count in COUNTS:
                if after[count] != before[count]:
                    rows.append(Row(f"{direction} {bus} {count}", str(before[count]), str(after[count]),
                                    after[count] > before[count]))
            for pct, key in ((latency_pct, "p50_ms"), (p99_pct, "p99_ms"), (None, "max_ms")):
                b, a = before["latency"].get(key), after["latency"].get(key)
                if b is None or a is None:
                    continue
                worse = pct is not None and a > b * (1 + pct / 100) and a - b > floor_ms
                change = f"{(a / b - 1) * 100:+.0f}%" if b > 0 else f"{a - b:+.3f} ms from {b:.3f}"  # no ratio of 0
                note = change + (f" (limit +{pct:g}% and +{floor_ms:g} ms)" if pct is not None else "")
                rows.append(Row(f"{direction} {bus} {key}", f"{b:.3f}", f"{a:.3f}", worse, note))
    return rows


def render(rows: list[Row], old: dict, new: dict) -> str:
    lines = [f"compare {old.get('run_id')} -> {new.get('run_id')} ({new.get('scenario')})"]
    if old.get("scenario") != new.get("scenario"):
        lines.append(f"note: different scenarios ({old.get('scenario')} vs {new.get('scenario')})")
    width = max([len(r.what) for r in rows] + [10])
    for r in rows:
        flag = "REGRESSION" if r.regression else ""
        lines.append(f"  {r.what:<{width}}  {r.old:>10} -> {r.new:<10} {r.note:<32} {flag}")
    regressions = sum(r.regression for r in rows)
    lines.append(f"{regressions} regression(s)" if regressions else "no regression")
    return "\n".join(lines)
