#!/usr/bin/env python3
"""QoS benchmark (make bench-qos, part of make bench): what zenoh-node's CAN -> Zenoh QoS
table (--rx-qos, docs/bridge.md) buys, in one run on one machine (docs/benchmark.md).

- **Priority under a flood**: a high-priority id (HIGH_ID, HIGH_FPS frames/s) and a flood of a
  low-priority id (FLOOD_ID, as fast as the bus takes FLOOD_FPS offered) on one bus for
  FLOOD_S, CAN -> Zenoh in immediate mode, client mode via zenohd. Latency p50/p99/max of the
  high id: alone (no flood), under the flood without a table (one class: it waits behind the
  flood in the bridge's queue and Zenoh's), and under the flood with the table
  PRIORITY_TABLE (realtime + express for 0x000-0x0FF, the flood data) and with the flood's
  class drop. Ratios: p50/p99 without the table over with it.
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
from .stamps import load_rate, zenoh_stamps

HIGH_ID, FLOOD_ID, STEADY_ID = 0x010, 0x600, 0x200
HIGH_FPS, FLOOD_FPS, FLOOD_S = 500, 200_000, 2.0
PRIORITY_TABLE = "0x000-0x0FF:realtime,express;0x100-0x7FF:data"
PRIORITY_VARIANTS = {  # name -> (flood on?, --rx-qos)
    "alone": (False, ""),
    "flood, no table": (True, ""),
    "flood, table": (True, PRIORITY_TABLE),
    "flood, table, flood drop": (True, "0x000-0x0FF:realtime,express;0x100-0x7FF:data,drop"),
}
STEADY_FPS, STEADY_S, PAUSE_AT_S, PAUSE_S = 10_000, 3.0, 0.5, 1.5
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

    def start_qos(self, bridge_args: list[str], connect_suffix: str = "") -> None:
        self.hub.start(["vcan0"])
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


def priority(args, name: str, flood: bool, table: str, seconds: float) -> dict:
    """The high id's latency, with or without a flood, with or without the table."""
    high_n, flood_n = int(HIGH_FPS * seconds), int(FLOOD_FPS * seconds)
    with tempfile.TemporaryDirectory(prefix="bench-qos-") as tmp:
        work = Path(tmp)
        rig = QosRig(args, work)
        try:
            rig.start_qos(["--rx-qos", table] if table else [])
            zn_out = work / "zenoh.tsv"
            rig.zn_capture("vehicle/can/rx", zn_out)
            pid = rig.bridge.pid if rig.bridge else 0
            cpu0, t0 = cpu_s(pid), time.monotonic()
            loads = [rig.can_load("send", "vcan0", f"{HIGH_ID:X}", HIGH_FPS, high_n)]
            if flood:
                loads.append(rig.can_load("send", "vcan0", f"{FLOOD_ID:X}", FLOOD_FPS, flood_n))
            wait_all(loads, name)
            flood_offered = load_rate(loads[1].stdout.read().decode(), flood_n) if flood else 0
            settle(lambda: len(zenoh_stamps(zn_out, HIGH_ID)), high_n, SETTLE_S, 0.05)
            settle(lambda: len(zenoh_stamps(zn_out)), high_n + (flood_n if flood else 0), 2.0, 0.05)
            stats = rig.stats()
            cpu = cpu_s(pid) - cpu0
            wall = time.monotonic() - t0
            high, bulk = zenoh_stamps(zn_out, HIGH_ID), zenoh_stamps(zn_out, FLOOD_ID)
        finally:
            rig.close()
    r = latency_summary(high, high_n)
    r.pop("cdf_us", None)
    r.update(variant=name, table=table, high_fps=HIGH_FPS)
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
            router = rig.router.proc
            assert router is not None

            def pause() -> None:  # the congestion, at a time of the load: the router takes nothing for pause_s
                time.sleep(PAUSE_AT_S)
                os.kill(router.pid, signal.SIGSTOP)
                try:
                    time.sleep(pause_s)
                finally:
                    os.kill(router.pid, signal.SIGCONT)
            pauser = threading.Thread(target=pause)
            pauser.start()
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
    ref = next((r for r in loss if r["variant"] == "reliable, block"), None)
    for r in loss:
        if ref and r is not ref:
            out[f"lost {r['variant']} / reliable, block"] = (round(r["lost"] / ref["lost"], 2) if ref["lost"]
                                                              else ("inf" if r["lost"] else 1.0))
    return out


def table_md(prio: list[dict], loss: list[dict], rat: dict) -> str:
    rows = [f"### High-priority id 0x{HIGH_ID:03X} ({HIGH_FPS}/s) under a flood of 0x{FLOOD_ID:03X} "
            f"(offered {FLOOD_FPS}/s), CAN -> Zenoh, client mode", "",
            "| variant | --rx-qos | p50 µs | p90 µs | p99 µs | max µs | high lost | flood offered/s "
            "| flood delivered/s | flood received | rx_queue_drops | bridge CPU % |", "|" + "---|" * 12]
    for r in prio:
        f = r.get("flood") or {}
        rows.append(f"| {r['variant']} | `{r['table'] or '-'}` | {r.get('p50_us', '-')} | {r.get('p90_us', '-')} | "
                    f"{r.get('p99_us', '-')} | {r.get('max_us', '-')} | {r['lost']} | {f.get('offered_fps', '-')} | "
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
                    help="0.5 s loads, the flood with and without the table, two QoS under congestion (a smoke run)")
    args = ap.parse_args()
    run_id, out = run_id_and_output(args)
    seconds = 0.5 if args.quick else FLOOD_S
    quick_set = ("flood, no table", "flood, table")
    variants = {k: v for k, v in PRIORITY_VARIANTS.items() if not args.quick or k in quick_set}
    prio = []
    for name, (flood, table) in variants.items():
        r = priority(args, name, flood, table, seconds)
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
