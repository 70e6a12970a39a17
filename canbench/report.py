"""report.html of a run, next to metrics.json in reports/<run-id>/: one
self-contained page: verdicts, latency histogram + CDF per direction, per-id
table, timeline, every gated signal over time (limits shaded, violations
marked), emulator fidelity, links to the run's files (recording.mcap, the ROS 2
recording, is canbench/recording.py's)."""
from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from . import wire

if TYPE_CHECKING:
    from .analysis import RunResult


SIGNAL_PLOTS = 40  # gated signals plotted (those with violations first); the table lists every one
ID_ROWS = 1000  # rows of the per-id table (ids with lost frames first); metrics.json cycle_times has every id
TIMELINE_BINS = 2000  # at most, however long the run: 100 ms bins up to 200 s of traffic, wider beyond

# ---- HTML ----

def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return f'<img alt="" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def _latency_plots(series: dict[str, Sequence[float]]) -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    series = {k: v for k, v in series.items() if v}
    if not series:
        return "<p>No latency samples.</p>"
    fig, (hist, cdf) = plt.subplots(1, 2, figsize=(11, 3.5))
    for name, values in series.items():
        hist.hist(values, bins=60, alpha=0.6, label=name)
        ordered = sorted(values)
        cdf.plot(ordered, [(i + 1) / len(ordered) for i in range(len(ordered))], label=name)
    hist.set_xlabel("latency (ms)")
    hist.set_ylabel("frames")
    hist.set_title("histogram")
    cdf.set_xlabel("latency (ms)")
    cdf.set_ylabel("fraction of frames")
    cdf.set_title("CDF")
    cdf.grid(alpha=0.3)
    hist.legend(fontsize=8)
    cdf.legend(fontsize=8)
    return _png(fig)


def _timeline(result: RunResult) -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    starts = [o.t_ns for b in result.buses for o in b.can_frames[:1] + b.commands[:1]]
    if not starts:
        return "<p>No traffic.</p>"
    t0 = min(starts)
    series = [(name, [(o.t_ns - t0) / 1e9 for o in frames]) for b in result.buses
              for name, frames in ((f"{b.bus} bus", b.can_frames), (f"{b.bus} Zenoh", b.zenoh_frames),
                                   (f"{b.bus} commands", b.commands)) if frames]
    span = max(max(times) - min(times) for _, times in series) if series else 0.0
    width = max(0.1, span / TIMELINE_BINS)  # 100 ms bins, wider on a long run (a 24 h soak: 864 001 of them)
    fig, ax = plt.subplots(figsize=(11, 3))
    for name, times in series:
        bins = max(1, min(TIMELINE_BINS, int((max(times) - min(times)) / width) + 1))
        ax.hist(times, bins=bins, histtype="step", label=name)
    for b in result.buses:
        lost = b.comparison.lost + (b.zenoh_to_can.lost if b.zenoh_to_can else [])
        if lost:
            ax.plot([(o.t_ns - t0) / 1e9 for o in lost], [0] * len(lost), "rx", label=f"{b.bus} lost")
    for window in (result.metrics.get("faults") or {}).get("windows", []):
        ax.axvspan((window["start_ns"] - t0) / 1e9, (window["end_ns"] - t0) / 1e9, color="orange", alpha=0.25)
        ax.annotate(window["action"], ((window["start_ns"] - t0) / 1e9, 0), fontsize=7, rotation=90)
    ax.set_xlabel("s since first frame")
    ax.set_ylabel("frames per 100 ms" if width == 0.1 else f"frames per {width:.3g} s")
    ax.legend(fontsize=8)
    return _png(fig)


def _bridge_resources(result: RunResult) -> str:
    """The bridge's memory and open descriptors over the run (sampled in fault scenarios and soaks)."""
    series = (result.metrics.get("faults") or {}).get("series") or {}
    if not series.get("rss"):
        return ""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (mem, fds) = plt.subplots(1, 2, figsize=(11, 3))
    mem.plot([t for t, _ in series["rss"]], [m for _, m in series["rss"]])
    mem.set_xlabel("s since traffic start")
    mem.set_ylabel("bridge memory (MiB)")
    slope = result.metrics["faults"]["bridge_rss_mib"].get("slope_mib_per_h")
    mem.set_title("memory" + (f" (slope {slope} MiB/h)" if slope is not None else ""))
    if series.get("fds"):
        fds.step([t for t, _ in series["fds"]], [n for _, n in series["fds"]], where="post")
    fds.set_xlabel("s since traffic start")
    fds.set_ylabel("open descriptors")
    fds.set_title("descriptors")
    for ax in (mem, fds):
        ax.grid(alpha=0.3)
        for window in result.metrics["faults"]["windows"]:
            ax.axvspan(window["start_s"], window["end_s"], color="orange", alpha=0.25)
    return "<h2>Bridge resources</h2>" + _png(fig)


def _signal_section(result: RunResult) -> str:
    """Every gated signal (expect.signals) over time, bus and Zenoh side: its limits shaded, its
    violations marked; the series are the evaluator's, thinned to a bound (canbench.signals)."""
    if not getattr(result.scenario, "signal_gates", ()):
        return ""
    from . import signals
    run = signals.evaluate(result)
    rows = [[s.bus, s.gate.key, s.side, s.count, "" if s.min is None else f"{s.min:.6g}",
             "" if s.max is None else f"{s.max:.6g}", s.violation_count, s.gate.limits()] for s in run.series]
    table = _table(["bus", "signal", "side", "values", "min", "max", "violations", "expected"], rows)
    plots: dict[tuple[str, str], list] = {}
    for s in sorted(run.series, key=lambda s: -s.violation_count):  # the violated first
        plots.setdefault((s.bus, s.gate.key), []).append(s)
    left_out = max(0, len(plots) - SIGNAL_PLOTS)
    plots = dict(list(plots.items())[:SIGNAL_PLOTS])
    for sides in plots.values():
        sides.sort(key=lambda s: s.side)  # bus, then Zenoh
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(plots), 1, figsize=(11, 2.4 * len(plots)), squeeze=False)
    for ax, ((bus, key), sides) in zip(axes[:, 0], plots.items(), strict=True):
        gate = sides[0].gate
        if gate.range:
            ax.axhspan(gate.range[0], gate.range[1], color="green", alpha=0.08, label="range")
            for limit in gate.range:
                ax.axhline(limit, color="green", lw=0.8, ls="--")
        for value in ([gate.equals] if gate.equals is not None else []) + list(gate.one_of or ()):
            ax.axhline(value, color="green", lw=0.8, ls=":")
        for s, colour in zip(sides, ("tab:blue", "tab:orange"), strict=False):
            if s.times:
                ax.plot(s.times, s.values, ".", ms=2, color=colour,
                        label=f"{'bus' if s.side == 'can' else 'Zenoh'} ({s.count})")
            if s.marks:
                ax.plot([t for t, _ in s.marks], [v for _, v in s.marks], "x", color="red", ms=7,
                        label=f"{'bus' if s.side == 'can' else 'Zenoh'} violations ({s.violation_count})")
        if gate.one_of is not None or (gate.equals is not None and gate.names):
            values = sorted(set(gate.names) | set(gate.one_of or ())
                            | ({gate.equals} if gate.equals is not None else set()))
            # the DBC's text as written: matplotlib reads what is between two '$' as mathtext
            # (a value table of $, $$, $$$ failed the whole report; US$ 1 to US$ 9 showed as math)
            ax.set_yticks(values, [f"{gate.names[v]} ({v:g})" if v in gate.names else f"{v:g}" for v in values],
                          fontsize=7, parse_math=False)
        ax.set_title(f"{bus} {key}{' (' + gate.unit + ')' if gate.unit else ''}: {gate.limits()}", fontsize=9,
                     parse_math=False)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("s since the first bus frame")
    fig.tight_layout()
    more = f"<p>{left_out} more gated signals (the fewest violations) are not plotted; the table lists them.</p>" \
        if left_out else ""
    return "<h2>Signals</h2>" + table + _png(fig) + more


def _response_section(m: dict) -> str:
    """Stimulus-response checks (expect.responses): counts and each rule's latency distribution."""
    rows = [[html.escape(name), r["bus"], r["side"], r["within_ms"], r["stimuli"], r["answered"], r["late"],
             r["missing"], r["duplicates"], _ms(r["latency"]["min_ms"]), _ms(r["latency"]["p50_ms"]),
             _ms(r["latency"]["p99_ms"]), _ms(r["latency"]["max_ms"])] for name, r in m.get("responses", {}).items()]
    if not rows:
        return ""
    return "<h2>Responses</h2>" + _table(["check", "bus", "side", "within ms", "stimuli", "answered", "late",
                                          "missing", "duplicates", "min ms", "p50 ms", "p99 ms", "max ms"], rows)


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c if str(c).startswith('<') else html.escape(str(c))}</td>"
                                    for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _ms(v) -> str:
    return "" if v is None else f"{v:.3f}"


def write_html(result: RunResult, path: Path) -> None:
    m = result.metrics
    verdicts = m.get("verdicts", {})
    problems = m.get("problems", {})
    verdict_rows = []
    for test, outcome in verdicts.items():
        check = test.split("[")[-1].rstrip("]")
        colour = {"passed": "pass", "failed": "fail"}.get(outcome, "skip")
        listed = "<br>".join(html.escape(p) for p in problems.get(check, []))
        verdict_rows.append([check, f'<span class="{colour}">{outcome}</span>', f"<small>{listed}</small>"])
    directions = [("CAN -> Zenoh", "can_to_zenoh"), ("Zenoh -> CAN", "zenoh_to_can"), ("round trip", "round_trip")]
    lat_rows = []
    for label, key in directions:
        for bus, s in m.get(key, {}).items():
            lat = s["latency"]
            disagrees = s.get("attachment_disagrees") or {}
            lat_rows.append([label, bus, s["sent"], s["matched"], s["lost"], s["duplicates"], s["corrupted"],
                             s["reordered"], _ms(lat.get("min_ms")), _ms(lat["p50_ms"]), _ms(lat["p90_ms"]),
                             _ms(lat["p99_ms"]), _ms(lat["max_ms"]),
                             " · ".join(f"{k} {v['count']}" for k, v in disagrees.items() if v["count"])])
    series: dict[str, Sequence[float]] = {}
    for b in result.buses:
        series[f"{b.bus} CAN->Zenoh"] = b.comparison.latency_ms
        if b.zenoh_to_can:
            series[f"{b.bus} Zenoh->CAN"] = b.zenoh_to_can.latency_ms
        if b.round_trip:
            series[f"{b.bus} round trip"] = b.round_trip.latency_ms
    id_rows = []
    for b in result.buses:
        lost_by_id: dict[str, int] = {}
        for o in b.comparison.lost:
            ident = wire.id_hex(o.frame.can_id, o.frame.extended)
            lost_by_id[ident] = lost_by_id.get(ident, 0) + 1
        for ident, sides in b.cycle_times.items():
            can, zen = sides["can"], sides["zenoh"] or {}
            id_rows.append([b.bus, ident, can["count"], zen.get("count", 0), lost_by_id.get(ident, 0),
                            _ms(can["cycle_p50_ms"]), _ms(zen.get("cycle_p50_ms")), _ms(zen.get("cycle_max_ms"))])
    left_out: list[list] = []
    if len(id_rows) > ID_ROWS:  # the ids with lost frames first, each bus's in its order otherwise
        id_rows = sorted(id_rows, key=lambda row: row[4] == 0)
        id_rows, left_out = id_rows[:ID_ROWS], id_rows[ID_ROWS:]
    lossy_left_out = sum(1 for row in left_out if row[4])
    ecu_rows = []
    for name, e in sorted(m.get("ecus", {}).items()):
        fid = e.get("fidelity_ms") or e.get("turnaround_ms") or {}
        ecu_rows.append([name, e.get("role", "replay"), e.get("bus"), e.get("sent"), _ms(fid.get("p50")),
                         _ms(fid.get("p99")), _ms(fid.get("max"))])
    files = [f for f in ("metrics.json", "junit.xml", "recording.mcap", "traffic.rrd", "can.log", "zenoh.tsv",
                         "commands.tsv", "containers.log") if (path.parent / f).exists() or f == "containers.log"]
    if m.get("device"):  # bench-run writes it beside the report: a device of your own's output
        files.append("device.log")
    files += sorted(p.name for p in path.parent.glob("ecu-*"))
    links = " · ".join(f'<a href="{f}">{f}</a>' for f in files)
    passed = m.get("passed")
    outcome = (m.get("validity") or {}).get("outcome", "valid")
    verdict = outcome.upper() if outcome != "valid" else "PASSED" if passed else "FAILED"
    device = ("· device under test " + html.escape(str(m["device"])) +
              (" (announces nothing: no token, no stats)" if m.get("device_announces") is False else "")
              if m.get("device") else "")
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(m['scenario'])} - canbench</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}} table{{border-collapse:collapse;margin:1em 0}}
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left;vertical-align:top}} .pass{{color:#080}}
.fail{{color:#c00;font-weight:bold}} .skip{{color:#888}} h1 .fail,h1 .pass{{font-size:80%}}</style></head><body>
<h1>{html.escape(m['scenario'])} <span class="{'pass' if passed else 'fail'}">{verdict}</span></h1>
<p>Run {html.escape(m['run_id'])} · traffic {m.get('traffic_s')} s · {html.escape(result.scenario.description)}
{device}
{'· baseline ' + html.escape(str(m['baseline_run_id'])) if m.get('baseline_run_id') else ''}</p>
<p>{links}</p>
<h2>Verdicts</h2>{_table(["check", "verdict", "problems"], verdict_rows)}
<h2>Frames and latency</h2>
{_table(["direction", "bus", "sent", "matched", "lost", "dup", "corrupted", "reordered", "min ms", "p50 ms",
         "p90 ms", "p99 ms", "max ms", "attachment disagrees"], lat_rows)}
{_latency_plots(series)}
<h2>Timeline</h2>{_timeline(result)}
{_bridge_resources(result)}
<h2>Per id</h2>
{_table(["bus", "id", "on bus", "on Zenoh", "lost", "bus cycle p50 ms", "Zenoh cycle p50 ms", "Zenoh max gap ms"],
        id_rows)}
{f"<p>{len(left_out)} more ids ({lossy_left_out} of them with lost frames) are in metrics.json cycle_times.</p>"
  if left_out else ""}
{_signal_section(result)}
{_response_section(m)}
<h2>Emulated ECUs</h2><p>Send-time error against the trace (echo: turnaround), so a verdict never blames the
bridge for the emulator's jitter.</p>
{_table(["ECU", "role", "bus", "sent", "p50 ms", "p99 ms", "max ms"], ecu_rows)}
</body></html>"""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(page, encoding="utf-8")  # as its <meta charset> says, whatever the locale
    tmp.replace(path)
