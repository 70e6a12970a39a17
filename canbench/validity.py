"""Is a run a valid test of the bridge? A verdict on the bridge needs a bench that worked:

  bench error        the oracle's result is impossible (a frame received before it was sent:
                     the bench's clocks or stamps are wrong), so no latency can be trusted
  invalid: capture   a capture could not keep up: candump's DROPCOUNT lines (the kernel's
                     SO_RXQ_OVFL counter), the hub's drops for candump's sockets, or zn-capture
                     wrote fewer samples than it counted
  invalid: emulator  a replay/periodic ECU fell behind its trace (more than 5 % of its frames
                     sent later than expect.emulator_max_send_error_ms: the p95 of its own send
                     error, robust to the odd scheduler stall of a loaded machine, which no
                     bridge check depends on) or its frames reached the bus out of the order it
                     sent them

An invalid run is judged on neither side: the bridge's checks are skipped, the run fails with
the outcome and its numbers (checks.valid_run; metrics.json `validity`)."""
from __future__ import annotations

import mmap
from pathlib import Path
from typing import TYPE_CHECKING

from . import oracle
from .capture import read_capture_stats
from .trace import DROPCOUNT

if TYPE_CHECKING:
    from .analysis import RunResult

OUTCOMES = ("bench error", "invalid: capture", "invalid: emulator")  # the first that applies wins
DEFAULT_EMULATOR_MAX_SEND_ERROR_MS = 5.0
SHOW = 5


def _frames(pairs) -> str:
    listed = ", ".join(f"{oracle.describe(s)} received {(r.t_ns - s.t_ns) / 1e6:.3f} ms" for s, r in pairs[:SHOW])
    return listed + (f", ... ({len(pairs) - SHOW} more)" if len(pairs) > SHOW else "")


def _stamp_cause(c: oracle.Comparison) -> str:
    """Why, when the bridge's stamps (SO_TIMESTAMPNS, in the attachment) are not candump's: the bus
    gave each reader its own time, as a userspace hub or preload library older than one stamp per
    frame does (docs/userspace-bus.md, Timestamps): a stale build or image, not the bridge."""
    stamp = (c.attachment or {}).get("can_stamp", {})
    if not stamp.get("count"):
        return ""
    return (f"; the bus gave its readers different stamps: the bridge's differ from candump's for {stamp['count']} "
            f"of {len(c.matched)} frames (up to {stamp['max_us']} us), as a ucan hub or preload built before one "
            f"stamp per frame does: rebuild ucan (make ucan) or the bus image")


def bench_errors(result: RunResult) -> list[str]:
    out = []
    for b in result.buses:
        for direction, c in (("CAN -> Zenoh", b.comparison), ("Zenoh -> CAN", b.zenoh_to_can),
                             ("round trip", b.round_trip)):
            negative = c.negative_latencies() if c is not None else []
            if c is not None and negative:
                worst = min((r.t_ns - s.t_ns) / 1e6 for s, r in negative)
                out.append(f"{b.bus} {direction}: {len(negative)} of {len(c.matched)} matched frames arrived before "
                           f"they were sent (min {worst:.3f} ms): the bench's stamps are wrong: {_frames(negative)}"
                           + _stamp_cause(c))
    return out


def dropcounts(path: Path) -> dict[str, int]:
    """Frames candump -d says the kernel dropped, per interface (a scan for its DROPCOUNT lines)."""
    out: dict[str, int] = {}
    if not path.exists() or path.stat().st_size == 0:
        return out
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as m:
        at = m.find(b"DROPCOUNT")
        while at >= 0:
            end = m.find(b"\n", at)
            match = DROPCOUNT.match(m[at:end if end >= 0 else len(m)].decode(errors="replace"))
            if match:
                out[match[2]] = out.get(match[2], 0) + int(match[1])
            at = m.find(b"DROPCOUNT", at + 1)
    return out


def capture_problems(result: RunResult) -> list[str]:
    out = [f"candump: the kernel dropped {n} frames on {iface} (DROPCOUNT in can.log)"
           for iface, n in sorted(dropcounts(result.run_dir / "can.log").items())]
    stats = read_capture_stats(result.run_dir)
    hub = stats.get("can", {}).get("hub_rx_drops")
    if hub:
        out.append(f"candump: the userspace hub dropped {hub} frames for candump's sockets (its queue was full)")
    zen = stats.get("zenoh", {})
    if zen.get("samples_reported") is not None and zen["samples_reported"] != zen.get("samples_written"):
        out.append(f"zn-capture counted {zen['samples_reported']} samples but zenoh.tsv holds "
                   f"{zen.get('samples_written')}")
    return out


def _send_log_order(path: Path, records: list[oracle.SentRecord]) -> str | None:
    """A send log whose frames do not follow their trace (send times going back, or trace lines
    out of order other than a loop starting again at its first line)."""
    first_line = records[0].source_line if records else 0
    bad = []
    for a, b in zip(records, records[1:], strict=False):
        if b.t_ns < a.t_ns or (b.source_line < a.source_line and b.source_line != first_line) or \
                (b.source_line == a.source_line != 0):
            bad.append(b)
    if not bad:
        return None
    return (f"{len(bad)} frames sent out of their trace order, first {path.name}:{bad[0].log_line} "
            f"(trace line {bad[0].source_line})")


def emulator_problems(result: RunResult) -> list[str]:
    limit = result.scenario.expect.get("emulator_max_send_error_ms", DEFAULT_EMULATOR_MAX_SEND_ERROR_MS)
    out = []
    for name, summary in sorted(result.ecus.items()):
        if summary.get("role", "replay") == "echo" or summary.get("killed"):
            continue
        error = summary.get("own_send_error_ms") or summary.get("fidelity_ms")
        if error and error["p95"] > limit:
            out.append(f"ECU {name}: p95 send error {error['p95']:.3f} ms > {limit} ms (p50 {error['p50']:.3f}, "
                       f"p99 {error['p99']:.3f}, max {error['max']:.3f} ms): it fell behind its trace")
        log = result.run_dir / f"ecu-{name}.sent.tsv"
        if log.exists():
            records = oracle.read_sent_log(log)
            order = _send_log_order(log, records)
            if order:
                out.append(f"ECU {name}: {order}")
            bus = summary.get("bus")
            # order only: stamped 0, so the ECU's clock (perf_counter mapped to the wall clock at its
            # start, which can drift from the bus's over an hour) never keeps a frame from matching
            sent = [oracle.Observed(r.frame, 0, i, line=r.log_line, origin=log.name)
                    for i, r in enumerate(records)]
            on_bus = next((b.bus_frames for b in result.buses if b.bus == bus), None)
            if on_bus and sent:
                reordered = oracle.match_subset(sent, on_bus).reordered
                if reordered:
                    out.append(f"ECU {name}: {len(reordered)} frames reached {bus} out of the order it sent them: "
                               + "; ".join(f"{oracle.describe(s)} after {oracle.describe(p)}"
                                           for s, p in reordered[:SHOW]))
    return out


def assess(result: RunResult) -> dict:
    """{"outcome": "valid" or the first of OUTCOMES that applies, "problems": {outcome: [...]}}."""
    problems = {"bench error": bench_errors(result), "invalid: capture": capture_problems(result),
                "invalid: emulator": emulator_problems(result)}
    problems = {k: v for k, v in problems.items() if v}
    outcome = next((k for k in OUTCOMES if k in problems), "valid")
    return {"outcome": outcome, "problems": problems}
