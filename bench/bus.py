#!/usr/bin/env python3
"""Userspace CAN bus benchmark (make bench-bus): throughput to several readers
and one-hop latency, each next to a baseline measured in the same run.

- throughput: cangen paced at N frames/ms into the hub, 3 candump readers
  writing to files; reports frames received per reader (lossless or not).
  Then the same without text formatting: can-load sending at an exact pace
  (not cangen's sleep-per-burst) to 3 can-load counting readers that also
  check the order.
- latency: hop_latency over the hub vs over a plain unix socketpair (the floor
  of any userspace bus), p50/p90/p99/max and the ratio hub/floor; and over a
  hub started with -s (busy-polls SPIN_US after each event: opt-in, it trades
  CPU for the hub's own wakeup).

Writes reports/bench/bus-<timestamp>.json and prints a markdown table.
Loopback only; every load is bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench.rig import Hub

from .common import REPO

READERS = 3
THROUGHPUT_FRAMES = 200_000
THROUGHPUT_RATES_PER_MS = (50, 100, 150, 250)
LATENCY_FRAMES = 20_000
LATENCY_RATES = (1_000, 10_000)
PACED_RATES = (100_000, 150_000)
SPIN_US = 50


def start_hub(build: Path, workdir: Path, *hub_args: str) -> Hub:
    hub = Hub(build, workdir)
    hub.start(["vcan0"], *hub_args)
    return hub


def throughput(hub: Hub, per_ms: int) -> dict:
    files = [hub.workdir / f"reader{i}.log" for i in range(READERS)]
    readers = [subprocess.Popen(["candump", "-L", "vcan0"], stdout=open(f, "w"), env=hub.env) for f in files]
    hub.wait_bound(READERS)
    start = time.monotonic()
    subprocess.run(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "1", "-c", str(per_ms),
                    "-n", str(THROUGHPUT_FRAMES), "-p", "100"], env=hub.env, check=True, timeout=120)
    elapsed = time.monotonic() - start
    stats = hub.stats()
    for r in readers:
        r.send_signal(signal.SIGINT)
        r.wait(timeout=30)
    received = [sum(1 for line in open(f) if line.startswith("(")) for f in files]
    hub.reset()
    return {"offered_per_s": per_ms * 1000, "achieved_per_s": round(THROUGHPUT_FRAMES / elapsed),
            "frames": THROUGHPUT_FRAMES, "received": received,
            "lossless": all(n == THROUGHPUT_FRAMES for n in received),
            "hub_drops": stats["interfaces"][0]["rx_drops"]}


def paced(hub: Hub, tools: Path, rate: int) -> dict:
    """can-load at an exact pace into 3 counting readers (no text formatting anywhere)."""
    readers = [subprocess.Popen([str(tools / "can-load"), "count", "vcan0", str(THROUGHPUT_FRAMES), "2000"],
                                stdout=subprocess.PIPE, text=True, env=hub.env) for _ in range(READERS)]
    hub.wait_bound(READERS)
    sent = json.loads(subprocess.run([str(tools / "can-load"), "send", "vcan0", "123", str(rate),
                                      str(THROUGHPUT_FRAMES)], capture_output=True, text=True, env=hub.env,
                                     check=True, timeout=120).stdout)
    counted = [json.loads(r.communicate(timeout=30)[0]) for r in readers]
    hub.reset()
    return {"offered_per_s": rate, "achieved_per_s": round(sent["frames"] / sent["seconds"]),
            "frames": THROUGHPUT_FRAMES, "received": [c["frames"] for c in counted],
            "out_of_order": sum(c["out_of_order"] for c in counted),
            "lossless": all(c["frames"] == THROUGHPUT_FRAMES and c["out_of_order"] == 0 for c in counted)}


def latency(tools: Path, env: dict, mode: str, rate: int) -> dict:
    out = subprocess.run([str(tools / "hop_latency"), mode, "vcan0" if mode == "can" else "-", str(LATENCY_FRAMES),
                          str(rate)], capture_output=True, text=True, env=env if mode == "can" else None, timeout=120)
    return {"mode": mode, "rate": rate, **json.loads(out.stdout)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", type=Path, default=REPO / "build" / "ucan", help="the hub, ucanctl, the preload")
    ap.add_argument("--tools", type=Path, default=REPO / "build" / "bench-tools", help="can-load, hop_latency")
    ap.add_argument("--out", type=Path, default=REPO / "reports" / "bench")
    args = ap.parse_args()
    build, tools = args.build.resolve(), args.tools.resolve()
    workdir = Path(tempfile.mkdtemp(prefix="ucan-bench-", dir="/tmp"))
    hub = start_hub(build, workdir)
    try:
        results = {
            "machine": {"cpus": os.cpu_count(), "kernel": os.uname().release},
            "throughput": [throughput(hub, r) for r in THROUGHPUT_RATES_PER_MS],
            "latency": [],
        }
        results["paced"] = [paced(hub, tools, r) for r in PACED_RATES]
        for rate in LATENCY_RATES:
            hub_lat, floor = latency(tools, hub.env, "can", rate), latency(tools, hub.env, "socketpair", rate)
            results["latency"] += [hub_lat, floor]
            hub_lat["p50_ratio_to_socketpair"] = round(hub_lat["p50_us"] / max(floor["p50_us"], 0.01), 1)
    finally:
        hub.stop()
    spin_dir = Path(tempfile.mkdtemp(prefix="ucan-bench-spin-", dir="/tmp"))
    hub = start_hub(build, spin_dir, "-s", str(SPIN_US))
    try:
        for rate in LATENCY_RATES:
            spun = latency(tools, hub.env, "can", rate)
            floor = next(r for r in results["latency"] if r["mode"] == "socketpair" and r["rate"] == rate)
            spun.update(mode=f"can-spin{SPIN_US}",
                        p50_ratio_to_socketpair=round(spun["p50_us"] / max(floor["p50_us"], 0.01), 1))
            results["latency"].append(spun)
    finally:
        hub.stop()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"bus-{time.strftime('%Y%m%d-%H%M%S')}.json"
    path.write_text(json.dumps(results, indent=2))
    print(f"| offered frames/s | achieved | received per reader (of {THROUGHPUT_FRAMES}) | lossless |")
    print("|---|---|---|---|")
    for t in results["throughput"]:
        print(f"| {t['offered_per_s']} | {t['achieved_per_s']} | {', '.join(map(str, t['received']))} | "
              f"{'yes' if t['lossless'] else 'no'} |")
    print(f"\n| paced (can-load) frames/s | achieved | received per counting reader (of {THROUGHPUT_FRAMES}) "
          "| out of order | lossless |")
    print("|---|---|---|---|---|")
    for t in results["paced"]:
        print(f"| {t['offered_per_s']} | {t['achieved_per_s']} | {', '.join(map(str, t['received']))} | "
              f"{t['out_of_order']} | {'yes' if t['lossless'] else 'no'} |")
    names = {"can": "hub", "socketpair": "socketpair", f"can-spin{SPIN_US}": f"hub -s {SPIN_US}"}
    print("\n| path | frames/s | p50 µs | p90 µs | p99 µs | max µs | p50 vs socketpair |")
    print("|---|---|---|---|---|---|---|")
    for lat in results["latency"]:
        print(f"| {names[lat['mode']]} | {lat['rate']} | {lat['p50_us']} | "
              f"{lat['p90_us']} | {lat['p99_us']} | {lat['max_us']} | {lat.get('p50_ratio_to_socketpair', '')} |")
    print(f"\nwritten: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
