#!/usr/bin/env python3
"""QoS benchmark (make bench-qos, part of make bench): what zenoh-node's CAN -> Zenoh QoS
table (--rx-qos, docs/bridge.md) buys, in one run on one machine (docs/benchmark.md).

- **Priority under a flood**: a high-priority id (HIGH_ID, HIGH_FPS frames/s) and a flood of a
  low-priority id (FLOOD_ID, FLOOD_FPS offered: more than the bus carries) on one bus paced at
  BUS_BITRATE (the hub arbitrates by id, as a real bus: the flood saturates the wire, the high
  id still wins it) for FLOOD_S, CAN -> Zenoh in immediate mode, client mode via zenohd, the
  Zenoh side congested: zenohd stopped for PAUSE_S at PAUSE_AT_S (the bridge's TCP send buffer
  small). Latency p50/p99/max of the high id: alone (no flood), under the flood without a table
  (one class: it waits behind the flood's backlog in the bridge's queue and Zenoh's), with the
  table PRIORITY_TABLE (realtime + express for 0x000-0x0FF, the flood data), with the
  flood's class drop and without express (Zenoh gives an express sample a batch of its own, and
  a priority has two: under a backlog a third put waits for a write, holding the bridge's one
  publisher thread), PRIORITY_RUNS runs of each, interleaved (one run's p99 on a shared machine
  says little): per variant the median of the runs' figures, the losses summed. A lost high
  frame is split by the attachment's sequence numbers: the bridge numbers every frame it reads,
  so one lost after that (its queue, Zenoh, the capture, still in flight) is a number missing;
  the rest never reached the bridge (the bus emulator's own loss, before any QoS). And when
  the frames the bridge read during the stop arrived after it: the high id's median and last,
  the flood's last (its backlog worked off). Ratios: p50/p99 without the table over with it.
- **Loss under a congested router**: a steady load (STEADY_FPS frames/s of STEADY_ID) while
  zenohd is stopped (SIGSTOP) for PAUSE_S and continued, the bridge's TCP send buffer small
  (so_sndbuf, so Zenoh's own queue fills rather than the kernel's); per QoS of the one class
  (reliable/best-effort x block/drop, through the table): frames lost, the bridge's own
  rx_queue_drops, max latency. Ratio: loss of each against reliable + block.

Every load frame carries its send time (can-load), so the capture gives each frame's latency
and loss is counted by stamp. Writes qos.json and qos.md into --out. Loopback only; every load
is bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from canbench import wire
from canbench.capture import iter_zenoh_capture
from canbench.errors import RunError
from canbench.rig import Router, bridge_stats, start_bridge

from .common import REPO, add_tool_arguments, cpu_s, machine_line, run_id_and_output, settle
from .paths import PathRig, latency_summary
from .stamps import load_rate, zenoh_frames, zenoh_stamps

HIGH_ID, FLOOD_ID, STEADY_ID = 0x010, 0x600, 0x200
HIGH_FPS, FLOOD_FPS, FLOOD_S = 500, 12_000, 3.0
BUS_BITRATE = 1_000_000  # 8-byte frames: ~8 800 frames/s on the wire
PRIORITY_TABLE = "0x000-0x0FF:realtime,express;0x100-0x7FF:data"
PRIORITY_VARIANTS = {  # name -> (flood on?, --rx-qos)
    "alone": (False, ""),
    "flood, no table": (True, ""),
    "flood, table": (True, PRIORITY_TABLE),
    "flood, table, flood drop": (True, "0x000-0x0FF:realtime,express;0x100-0x7FF:data,drop"),
    "flood, table, no express": (True, "0x000-0x0FF:realtime;0x100-0x7FF:data"),
}
STEADY_FPS, STEADY_S, PAUSE_AT_S, PAUSE_S = 10_000, 3.0, 0.5, 1.5
PRIORITY_PAUSE_S = 0.5
PRIORITY_RUNS = 3  # of each variant: single runs' p50 and loss differed 2x, p99 10x (shared 2 cores)
SNDBUF = 4096  # the bridge's TCP send buffer (the kernel doubles it): Zenoh's queue is what fills
RELIABILITY_VARIANTS = {  # the one class's QoS, through the table
    "reliable, block": "0x000-0x7FF:reliable,block",
    "best-effort, block": "0x000-0x7FF:best-effort,block",
    "reliable, drop": "0x000-0x7FF:reliable,drop",
    "best-effort, drop": "0x000-0x7FF:best-effort,drop",
}
SETTLE_S = 10.0


class QosRig(PathRig):
    """A private hub, zenohd (kept, to stop and continue it) and zenoh-node with extra flags."""

    def start_qos(self, bridge_args: list[str], connect_suffix: str = "", iface: str = "vcan0") -> None:
        self.hub.start([iface])
        self.router = Router(self.args.zenohd)
        self.procs.add(self.router.start())
        self.endpoint = self.router.endpoint
        cmd = [self.args.bridge, "--can", "vcan0", "--publish-period-ms", "0",
               "--router", self.router.endpoint + connect_suffix, *bridge_args]
        with self.session() as s:
            try:
                self.bridge = start_bridge(self.procs, cmd, self.env, self.workdir / "bridge.log", s,
                                           "vehicle/can/bridges/**", cwd=REPO)
            except RunError as e:
                sys.exit(f"zenoh-node {' '.join(bridge_args)} did not come up: {e}")

    def stats(self) -> dict:
        with self.session() as s:
            return (bridge_stats(s) or {"buses": [{}]})["buses"][0]


def wait_all(procs: list[subprocess.Popen], what: str) -> None:
    for p in procs:
        p.wait()
        if p.returncode != 0:
            raise RuntimeError(f"{what}: load exited {p.returncode}")


def paused_router(router: subprocess.Popen, at_s: float, pause_s: float,
                  window: list | None = None) -> threading.Thread:
    """The congestion, at a time of the load: the router takes nothing for pause_s, then resumes;
    window gets the stop's start and end (CLOCK_REALTIME ns, the clock of the frames' stamps)."""
    def pause() -> None:
        time.sleep(at_s)  # when, in the load, the fault starts (not a synchronisation)
        os.kill(router.pid, signal.SIGSTOP)
        start = time.time_ns()
        try:
            time.sleep(pause_s)
        finally:
            os.kill(router.pid, signal.SIGCONT)
            if window is not None:
                window.extend([start, time.time_ns()])
    t = threading.Thread(target=pause)
    t.start()
    return t


def sequence_numbers(path: Path) -> set[int]:
    """The sequence numbers a zn-capture TSV holds (zenoh-node's attachment: the first frame's, then
    one more per frame of a batch)."""
    seqs: set[int] = set()
    for sample in iter_zenoh_capture(path, growing=True):
        try:
            att = wire.decode_attachment(sample.attachment) if sample.attachment else None
        except wire.WireError:
            att = None
        if att:
            seqs.update(range(att.first_seq, att.first_seq + len(att.rx_times_ns)))
    return seqs


def split_loss(lost: int, numbered: int, seqs: set[int]) -> dict:
    """A load's lost frames split at the bridge: numbered frames read (sequence numbers
    0..numbered-1, every id), seqs those the capture holds. Those missing were lost after the
    bridge read them, of whatever id; a lost frame of this load can be one of them, or else the
    bridge never read it (lost on the bus). With no number missing the split is exact."""
    after = numbered - len(seqs & set(range(numbered)))
    after_load = min(lost, after)
    return {"lost_after_bridge_read_all_ids": after, "lost_after_bridge_read_at_most": after_load,
            "lost_before_bridge_at_least": lost - after_load}


def not_caught_by_stop(from_stamp: list[tuple[int, int]], window: list[int]) -> list[tuple[int, int]]:
    """(CAN stamp, receive ns) of the frames the stop did not catch: read after it, or read and
    delivered before it (a frame read just before it, still on its way, waited through it)."""
    if not window:
        return from_stamp
    return [(rx, recv) for rx, recv in from_stamp if rx > window[1] or recv < window[0]]


def backlog_after_resume(high: list[tuple[int, int]], bulk: list[tuple[int, int]], window: list[int]) -> dict:
    """When the frames the bridge read during the stop arrived, ms after zenohd was continued: the
    high id's median and last, the flood's last (its backlog worked off): what the table orders."""
    def after(frames: list[tuple[int, int]]) -> list[float]:
        return sorted((recv - window[1]) / 1e6 for rx, recv in frames if window and window[0] <= rx <= window[1])
    h, b = after(high), after(bulk)
    return {"high_p50": round(statistics.median(h), 1) if h else None, "high_max": round(h[-1], 1) if h else None,
            "flood_max": round(b[-1], 1) if b else None}


def priority(args, name: str, flood: bool, table: str, seconds: float, pause_s: float) -> dict:
    """The high id's latency, with or without a flood, with or without the table."""
    high_n, flood_n = int(HIGH_FPS * seconds), int(FLOOD_FPS * seconds)
    with tempfile.TemporaryDirectory(prefix="bench-qos-") as tmp:
        work = Path(tmp)
        rig = QosRig(args, work)
        try:
            rig.start_qos(["--rx-qos", table] if table else [], f"#so_sndbuf={SNDBUF}",
                          f"vcan0:bitrate={BUS_BITRATE}")
            zn_out = work / "zenoh.tsv"
            rig.zn_capture("vehicle/can/rx", zn_out)
            pid = rig.bridge.pid if rig.bridge else 0
            cpu0, t0 = cpu_s(pid), time.monotonic()
            loads = [rig.can_load("send", "vcan0", f"{HIGH_ID:X}", HIGH_FPS, high_n)]
            if flood:
                loads.append(rig.can_load("send", "vcan0", f"{FLOOD_ID:X}", FLOOD_FPS, flood_n))
            assert rig.router.proc is not None
            window: list[int] = []
            pauser = paused_router(rig.router.proc, PAUSE_AT_S, pause_s, window)
            try:
                wait_all(loads, name)
            finally:
                pauser.join()
            flood_offered = load_rate(loads[1].stdout.read().decode(), flood_n) if flood else 0
            settle(lambda: len(zenoh_stamps(zn_out, HIGH_ID)), high_n, SETTLE_S, 0.05)
            settle(lambda: len(zenoh_stamps(zn_out)), high_n + (flood_n if flood else 0), 2.0, 0.05)
            stats = rig.stats()
            numbered = (stats.get("can_rx_frames", 0) - stats.get("filtered", 0) - stats.get("invalid_frames", 0))
            seqs = sequence_numbers(zn_out)
            cpu = cpu_s(pid) - cpu0
            wall = time.monotonic() - t0
            high, bulk = zenoh_stamps(zn_out, HIGH_ID), zenoh_stamps(zn_out, FLOOD_ID)
            # from the bridge's CAN receive stamp (its attachment) on: what the table acts on, without
            # the bus's own queueing before the bridge's socket
            from_stamp = [(rx, recv) for fid, _, recv, rx in zenoh_frames(zn_out) if fid == HIGH_ID and rx]
            flood_stamp = [(rx, recv) for fid, _, recv, rx in zenoh_frames(zn_out) if fid == FLOOD_ID and rx]
        finally:
            rig.close()
    r = latency_summary(high, high_n)
    r.pop("cdf_us", None)
    bridge = latency_summary(from_stamp, len(from_stamp))
    r["from_can_stamp"] = {k: bridge.get(k) for k in ("p50_us", "p90_us", "p99_us", "max_us")}
    # the frames the stop did not catch: those that could move, and either waited behind the
    # flood's backlog after it or overtook it
    moving = not_caught_by_stop(from_stamp, window)
    outside = latency_summary(moving, len(moving))
    r["from_can_stamp_outside_stop"] = {k: outside.get(k) for k in ("p50_us", "p90_us", "p99_us", "max_us")}
    r["after_resume_ms"] = backlog_after_resume(from_stamp, flood_stamp, window)
    r.update(variant=name, table=table, high_fps=HIGH_FPS, pause_s=pause_s,
             **split_loss(r["lost"], numbered, seqs))
    if flood:
        flood_sum = latency_summary(bulk, flood_n)
        r["flood"] = {"offered_fps": flood_offered, "sent": flood_n, "received": flood_sum["received"],
                      "delivered_fps": flood_sum.get("delivered_fps"), "p50_us": flood_sum.get("p50_us")}
    r.update(bridge_cpu_pct=round(100 * cpu / wall, 1), rx_queue_drops=stats.get("rx_queue_drops"),
             published_frames=stats.get("published_frames"), rx_classes=stats.get("rx_classes"))
    return r


SUMMED = ("sent", "received", "duplicates", "lost", "lost_after_bridge_read_all_ids", "lost_after_bridge_read_at_most",
          "lost_before_bridge_at_least", "rx_queue_drops", "published_frames")


def median_of(values: list) -> float | None:
    present = [v for v in values if isinstance(v, (int, float))]
    return round(statistics.median(present), 1) if present else None


def combine(runs: list[dict]) -> dict:
    """Several runs of one variant as one row: counts summed, every other figure the runs' median;
    each run's own figures kept in "runs"."""
    first = runs[0]
    r: dict = {k: v for k, v in first.items() if not isinstance(v, (int, float, dict)) or isinstance(v, bool)}
    for k, v in first.items():
        if k in SUMMED:
            r[k] = sum(x.get(k) or 0 for x in runs)
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            r[k] = median_of([x.get(k) for x in runs]) if k not in ("high_fps", "pause_s") else v
        elif isinstance(v, dict):
            r[k] = {kk: (sum((x.get(k) or {}).get(kk) or 0 for x in runs) if kk in SUMMED
                         else median_of([(x.get(k) or {}).get(kk) for x in runs])) for kk in v}
    r["runs"] = [{"lost": x["lost"], "lost_after_bridge_read_all_ids": x.get("lost_after_bridge_read_all_ids"),
                  "p50_us": x.get("p50_us"), "from_can_stamp": x.get("from_can_stamp"),
                  "from_can_stamp_outside_stop": x.get("from_can_stamp_outside_stop")} for x in runs]
    return r


def congested(args, name: str, table: str, seconds: float, pause_s: float) -> dict:
    """Loss and latency of a steady load while zenohd is stopped for pause_s."""
    count = int(STEADY_FPS * seconds)
    with tempfile.TemporaryDirectory(prefix="bench-qos-") as tmp:
        work = Path(tmp)
        rig = QosRig(args, work)
        try:
            rig.start_qos(["--rx-qos", table], f"#so_sndbuf={SNDBUF}")
            zn_out = work / "zenoh.tsv"
            rig.zn_capture("vehicle/can/rx", zn_out)
            load = rig.can_load("send", "vcan0", f"{STEADY_ID:X}", STEADY_FPS, count)
            assert rig.router.proc is not None
            pauser = paused_router(rig.router.proc, PAUSE_AT_S, pause_s)
            try:
                wait_all([load], name)
            finally:
                pauser.join()
            settle(lambda: len(zenoh_stamps(zn_out, STEADY_ID)), count, SETTLE_S, 0.05)
            stats = rig.stats()
            stamps = zenoh_stamps(zn_out, STEADY_ID)
        finally:
            rig.close()
    r = latency_summary(stamps, count)
    r.pop("cdf_us", None)
    r.update(variant=name, table=table, fps=STEADY_FPS, pause_s=pause_s,
             loss_pct=round(100 * r["lost"] / count, 3), rx_queue_drops=stats.get("rx_queue_drops"),
             published_frames=stats.get("published_frames"))
    return r


def ratios(prio: list[dict], loss: list[dict]) -> dict:
    out: dict = {}
    by = {r["variant"]: r for r in prio}
    base = by.get("flood, no table")
    for name, r in by.items():
        if base and name.startswith("flood, table") and r.get("p99_us") and base.get("p99_us"):
            out[f"p50 no table / {name}"] = round(base["p50_us"] / r["p50_us"], 2)
            out[f"p99 no table / {name}"] = round(base["p99_us"] / r["p99_us"], 2)
            for key, words in (("from_can_stamp", "from the CAN stamp"),
                               ("from_can_stamp_outside_stop", "from the CAN stamp, not caught by the stop")):
                b, t = base.get(key) or {}, r.get(key) or {}
                if b.get("p99_us") and t.get("p99_us"):
                    out[f"{words}: p50 no table / {name}"] = round(b["p50_us"] / t["p50_us"], 2)
                    out[f"{words}: p99 no table / {name}"] = round(b["p99_us"] / t["p99_us"], 2)
    ref = next((r for r in loss if r["variant"] == "reliable, block"), None)
    for r in loss:
        if ref and r is not ref:
            out[f"lost {r['variant']} / reliable, block"] = (round(r["lost"] / ref["lost"], 2) if ref["lost"]
                                                              else ("inf" if r["lost"] else 1.0))
    return out


def table_md(prio: list[dict], loss: list[dict], rat: dict) -> str:
    n_runs = len(prio[0].get("runs") or [0]) if prio else 1
    rows = [f"### High-priority id 0x{HIGH_ID:03X} ({HIGH_FPS}/s) under a flood of 0x{FLOOD_ID:03X} "
            f"(offered {FLOOD_FPS}/s on a {BUS_BITRATE // 1000} kbit/s bus), CAN -> Zenoh, client mode, zenohd "
            f"stopped for {prio[0].get('pause_s', PRIORITY_PAUSE_S) if prio else PRIORITY_PAUSE_S} s", "",
            f"Median of {n_runs} run{'s' if n_runs != 1 else ''} per variant (interleaved), "
            "counts summed. High lost: all / of them at most lost after the bridge read them (the "
            "sequence numbers missing, any id) / the rest never read by the bridge (lost on the bus).", "",
            "| variant | --rx-qos | p50 µs | p90 µs | p99 µs | max µs | from CAN stamp p50 / p99 / max µs "
            "| same, not caught by the stop | high lost / after bridge / bus | flood offered/s | flood delivered/s "
            "| flood received | rx_queue_drops | bridge CPU % | read in the stop, arrived after it: high p50 / max, "
            "flood max ms |", "|" + "---|" * 15]
    for r in prio:
        f = r.get("flood") or {}
        b, o = r.get("from_can_stamp") or {}, r.get("from_can_stamp_outside_stop") or {}
        a = r.get("after_resume_ms") or {}
        rows.append(f"| {r['variant']} | `{r['table'] or '-'}` | {r.get('p50_us', '-')} | {r.get('p90_us', '-')} | "
                    f"{r.get('p99_us', '-')} | {r.get('max_us', '-')} | {b.get('p50_us', '-')} / "
                    f"{b.get('p99_us', '-')} / {b.get('max_us', '-')} | {o.get('p50_us', '-')} / "
                    f"{o.get('p99_us', '-')} / {o.get('max_us', '-')} | {r['lost']} / "
                    f"{r.get('lost_after_bridge_read_at_most', '-')} / {r.get('lost_before_bridge_at_least', '-')} | "
                    f"{f.get('offered_fps', '-')} | "
                    f"{f.get('delivered_fps', '-')} | {f.get('received', '-')}/{f.get('sent', '-')} | "
                    f"{r.get('rx_queue_drops')} | {r.get('bridge_cpu_pct')} | {a.get('high_p50', '-')} / "
                    f"{a.get('high_max', '-')} / {a.get('flood_max', '-')} |")
    if any(len(r.get("runs") or []) > 1 for r in prio):
        rows += ["", "Per run, from the CAN stamp, not caught by the stop, p50 / p99 µs (high lost, of which "
                 "numbers missing after the bridge):", ""]
        for r in prio:
            runs = "; ".join(f"{(x.get('from_can_stamp_outside_stop') or {}).get('p50_us', '-')} / "
                             f"{(x.get('from_can_stamp_outside_stop') or {}).get('p99_us', '-')} "
                             f"({x['lost']}, {x.get('lost_after_bridge_read_all_ids', '-')})" for x in r["runs"])
            rows.append(f"- {r['variant']}: {runs}")
    rows += ["", f"### Loss of 0x{STEADY_ID:03X} at {STEADY_FPS}/s while zenohd is stopped for "
             f"{loss[0]['pause_s'] if loss else PAUSE_S} s (bridge so_sndbuf {SNDBUF})", "",
             "| QoS | lost | lost % | rx_queue_drops | p50 µs | max µs |", "|---|---|---|---|---|---|"]
    for r in loss:
        rows.append(f"| {r['variant']} | {r['lost']}/{r['sent']} | {r['loss_pct']} | {r.get('rx_queue_drops')} | "
                    f"{r.get('p50_us', '-')} | {r.get('max_us', '-')} |")
    rows += ["", "### Ratios", ""] + [f"- {k}: {v}" for k, v in rat.items()]
    return "\n".join(rows)


def chosen_variants(text: str | None) -> set[str]:
    """--variants: names of PRIORITY_VARIANTS and RELIABILITY_VARIANTS, ':' for ', ' (a comma
    separates them); an unknown one ends the run before anything starts."""
    if not text:
        return set()
    names = {n.strip().replace(":", ", ") for n in text.split(",") if n.strip()}
    unknown = names - set(PRIORITY_VARIANTS) - set(RELIABILITY_VARIANTS)
    if unknown:
        sys.exit(f"--variants: unknown {', '.join(sorted(unknown))}; known: "
                 + ", ".join(n.replace(", ", ":") for n in list(PRIORITY_VARIANTS) + list(RELIABILITY_VARIANTS)))
    return names


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--quick", action="store_true",
                    help="1.5 s loads, the flood with and without the table, two QoS under congestion (a smoke run)")
    ap.add_argument("--variants", help="only these variants, comma separated names (e.g. 'flood, table' is "
                    "flood:table): " + ", ".join(list(PRIORITY_VARIANTS) + list(RELIABILITY_VARIANTS)))
    ap.add_argument("--runs", type=int, help=f"runs of each priority variant (default {PRIORITY_RUNS}, --quick 1)")
    args = ap.parse_args()
    chosen = chosen_variants(args.variants)
    runs = args.runs or (1 if args.quick else PRIORITY_RUNS)
    run_id, out = run_id_and_output(args)
    seconds = 1.5 if args.quick else FLOOD_S
    quick_set = ("flood, no table", "flood, table")
    variants = {k: v for k, v in PRIORITY_VARIANTS.items()
                if (k in chosen if chosen else not args.quick or k in quick_set)}
    by_variant: dict[str, list[dict]] = {name: [] for name in variants}
    for _ in range(runs):  # interleaved: a slower stretch of the machine touches every variant alike
        for name, (flood, table) in variants.items():
            r = priority(args, name, flood, table, seconds, 0.3 if args.quick else PRIORITY_PAUSE_S)
            print(json.dumps(r), flush=True)
            by_variant[name].append(r)
    prio = [combine(rs) for rs in by_variant.values()]
    loss_variants = {k: v for k, v in RELIABILITY_VARIANTS.items()
                     if (k in chosen if chosen else not args.quick or k in ("reliable, block", "best-effort, drop"))}
    loss = []
    for name, table in loss_variants.items():
        r = congested(args, name, table, 1.5 if args.quick else STEADY_S, 0.5 if args.quick else PAUSE_S)
        print(json.dumps(r), flush=True)
        loss.append(r)
    rat = ratios(prio, loss)
    machine = machine_line()
    (out / "qos.json").write_text(json.dumps({"run_id": run_id, "machine": machine, "quick": args.quick,
                                              "priority": prio, "congestion": loss, "ratios": rat}, indent=1))
    md = table_md(prio, loss, rat)
    (out / "qos.md").write_text(f"QoS benchmark {run_id} on {machine}{' (quick)' if args.quick else ''}\n\n{md}\n")
    print(md)
    print(f"written: {out}/qos.json, qos.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
