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
  table PRIORITY_TABLE (realtime + express for 0x000-0x0FF, the flood data) and with the
  flood's class drop. Ratios: p50/p99 without the table over with it.
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
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

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
}
STEADY_FPS, STEADY_S, PAUSE_AT_S, PAUSE_S = 10_000, 3.0, 0.5, 1.5
PRIORITY_PAUSE_S = 0.5
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
            cpu = cpu_s(pid) - cpu0
            wall = time.monotonic() - t0
            high, bulk = zenoh_stamps(zn_out, HIGH_ID), zenoh_stamps(zn_out, FLOOD_ID)
            # from the bridge's CAN receive stamp (its attachment) on: what the table acts on, without
            # the bus's own queueing before the bridge's socket
            from_stamp = [(rx, recv) for fid, _, recv, rx in zenoh_frames(zn_out) if fid == HIGH_ID and rx]
        finally:
            rig.close()
    r = latency_summary(high, high_n)
    r.pop("cdf_us", None)
    bridge = latency_summary(from_stamp, len(from_stamp))
    r["from_can_stamp"] = {k: bridge.get(k) for k in ("p50_us", "p90_us", "p99_us", "max_us")}
    # the frames the bridge read outside the stop: those that could move, and either waited behind
    # the flood's backlog or overtook it
    moving = [(rx, recv) for rx, recv in from_stamp if not window or not window[0] <= rx <= window[1]]
    outside = latency_summary(moving, len(moving))
    r["from_can_stamp_outside_stop"] = {k: outside.get(k) for k in ("p50_us", "p90_us", "p99_us", "max_us")}
    r.update(variant=name, table=table, high_fps=HIGH_FPS, pause_s=pause_s)
    if flood:
        flood_sum = latency_summary(bulk, flood_n)
        r["flood"] = {"offered_fps": flood_offered, "sent": flood_n, "received": flood_sum["received"],
                      "delivered_fps": flood_sum.get("delivered_fps"), "p50_us": flood_sum.get("p50_us")}
    r.update(bridge_cpu_pct=round(100 * cpu / wall, 1), rx_queue_drops=stats.get("rx_queue_drops"),
             published_frames=stats.get("published_frames"), rx_classes=stats.get("rx_classes"))
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
                               ("from_can_stamp_outside_stop", "from the CAN stamp, outside the stop")):
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
    rows = [f"### High-priority id 0x{HIGH_ID:03X} ({HIGH_FPS}/s) under a flood of 0x{FLOOD_ID:03X} "
            f"(offered {FLOOD_FPS}/s on a {BUS_BITRATE // 1000} kbit/s bus), CAN -> Zenoh, client mode, zenohd "
            f"stopped for {prio[0].get('pause_s', PRIORITY_PAUSE_S) if prio else PRIORITY_PAUSE_S} s", "",
            "| variant | --rx-qos | p50 µs | p90 µs | p99 µs | max µs | from CAN stamp p50 / p99 / max µs "
            "| same, read outside the stop | high lost | flood offered/s | flood delivered/s | flood received "
            "| rx_queue_drops | bridge CPU % |", "|" + "---|" * 14]
    for r in prio:
        f = r.get("flood") or {}
        b, o = r.get("from_can_stamp") or {}, r.get("from_can_stamp_outside_stop") or {}
        rows.append(f"| {r['variant']} | `{r['table'] or '-'}` | {r.get('p50_us', '-')} | {r.get('p90_us', '-')} | "
                    f"{r.get('p99_us', '-')} | {r.get('max_us', '-')} | {b.get('p50_us', '-')} / "
                    f"{b.get('p99_us', '-')} / {b.get('max_us', '-')} | {o.get('p50_us', '-')} / "
                    f"{o.get('p99_us', '-')} / {o.get('max_us', '-')} | {r['lost']} | {f.get('offered_fps', '-')} | "
                    f"{f.get('delivered_fps', '-')} | {f.get('received', '-')}/{f.get('sent', '-')} | "
                    f"{r.get('rx_queue_drops')} | {r.get('bridge_cpu_pct')} |")
    rows += ["", f"### Loss of 0x{STEADY_ID:03X} at {STEADY_FPS}/s while zenohd is stopped for "
             f"{loss[0]['pause_s'] if loss else PAUSE_S} s (bridge so_sndbuf {SNDBUF})", "",
             "| QoS | lost | lost % | rx_queue_drops | p50 µs | max µs |", "|---|---|---|---|---|---|"]
    for r in loss:
        rows.append(f"| {r['variant']} | {r['lost']}/{r['sent']} | {r['loss_pct']} | {r.get('rx_queue_drops')} | "
                    f"{r.get('p50_us', '-')} | {r.get('max_us', '-')} |")
    rows += ["", "### Ratios", ""] + [f"- {k}: {v}" for k, v in rat.items()]
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--quick", action="store_true",
                    help="1.5 s loads, the flood with and without the table, two QoS under congestion (a smoke run)")
    args = ap.parse_args()
    run_id, out = run_id_and_output(args)
    seconds = 1.5 if args.quick else FLOOD_S
    quick_set = ("flood, no table", "flood, table")
    variants = {k: v for k, v in PRIORITY_VARIANTS.items() if not args.quick or k in quick_set}
    prio = []
    for name, (flood, table) in variants.items():
        r = priority(args, name, flood, table, seconds, 0.3 if args.quick else PRIORITY_PAUSE_S)
        print(json.dumps(r), flush=True)
        prio.append(r)
    loss_variants = {k: v for k, v in RELIABILITY_VARIANTS.items()
                     if not args.quick or k in ("reliable, block", "best-effort, drop")}
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
