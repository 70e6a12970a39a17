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

from .common import REPO

READERS = 3
THROUGHPUT_FRAMES = 200_000
THROUGHPUT_RATES_PER_MS = (50, 100, 150, 250)
LATENCY_FRAMES = 20_000
LATENCY_RATES = (1_000, 10_000)
PACED_RATES = (100_000, 150_000)
SPIN_US = 50


def start_hub(build: Path, workdir: Path, *hub_args: str) -> tuple[subprocess.Popen, dict]:
    env = dict(os.environ, UCAN_DIR=str(workdir), LD_PRELOAD=str(build / "libucan-preload.so"))
    read_fd, write_fd = os.pipe()
    hub = subprocess.Popen([str(build / "ucan-hub"), "-d", str(workdir), "-r", str(write_fd), *hub_args, "vcan0"],
                           pass_fds=(write_fd,), stderr=subprocess.DEVNULL, env={**env, "LD_PRELOAD": ""})
    os.close(write_fd)
    with os.fdopen(read_fd) as ready:
        if ready.readline().strip() != "ready":
            sys.exit("ucan-hub did not start")
    return hub, env


def bound_readers(build: Path, workdir: Path) -> int:
    out = subprocess.run([str(build / "ucanctl"), "-d", str(workdir), "stats", "-j"], capture_output=True, text=True)
    return sum(1 for c in json.loads(out.stdout)["clients"] if c["bound"]) if out.returncode == 0 else 0


def throughput(build: Path, workdir: Path, env: dict, per_ms: int) -> dict:
    files = [workdir / f"reader{i}.log" for i in range(READERS)]
    readers = [subprocess.Popen(["candump", "-L", "vcan0"], stdout=open(f, "w"), env=env) for f in files]
    deadline = time.monotonic() + 10
    while bound_readers(build, workdir) < READERS and time.monotonic() < deadline:
        time.sleep(0.01)  # polling the hub's own readiness count, bounded
    start = time.monotonic()
    subprocess.run(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "1", "-c", str(per_ms),
                    "-n", str(THROUGHPUT_FRAMES), "-p", "100"], env=env, check=True, timeout=120)
    elapsed = time.monotonic() - start
    stats = json.loads(subprocess.run([str(build / "ucanctl"), "-d", str(workdir), "stats", "-j"],
                                      capture_output=True, text=True, check=True).stdout)
    for r in readers:
        r.send_signal(signal.SIGINT)
        r.wait(timeout=30)
    received = [sum(1 for line in open(f) if line.startswith("(")) for f in files]
    subprocess.run([str(build / "ucanctl"), "-d", str(workdir), "reset"], check=True)
    return {"offered_per_s": per_ms * 1000, "achieved_per_s": round(THROUGHPUT_FRAMES / elapsed),
            "frames": THROUGHPUT_FRAMES, "received": received,
            "lossless": all(n == THROUGHPUT_FRAMES for n in received),
            "hub_drops": stats["interfaces"][0]["rx_drops"]}


def paced(build: Path, tools: Path, workdir: Path, env: dict, rate: int) -> dict:
    """can-load at an exact pace into 3 counting readers (no text formatting anywhere)."""
    readers = [subprocess.Popen([str(tools / "can-load"), "count", "vcan0", str(THROUGHPUT_FRAMES), "2000"],
                                stdout=subprocess.PIPE, text=True, env=env) for _ in range(READERS)]
    deadline = time.monotonic() + 10
    while bound_readers(build, workdir) < READERS and time.monotonic() < deadline:
        time.sleep(0.01)  # polling the hub's own readiness count, bounded
    sent = json.loads(subprocess.run([str(tools / "can-load"), "send", "vcan0", "123", str(rate),
                                      str(THROUGHPUT_FRAMES)], capture_output=True, text=True, env=env,
                                     check=True, timeout=120).stdout)
    counted = [json.loads(r.communicate(timeout=30)[0]) for r in readers]
    subprocess.run([str(build / "ucanctl"), "-d", str(workdir), "reset"], check=True)
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
    hub, env = start_hub(build, workdir)
    try:
        results = {
            "machine": {"cpus": os.cpu_count(), "kernel": os.uname().release},
            "throughput": [throughput(build, workdir, env, r) for r in THROUGHPUT_RATES_PER_MS],
            "latency": [],
        }
        results["paced"] = [paced(build, tools, workdir, env, r) for r in PACED_RATES]
        for rate in LATENCY_RATES:
            hub_lat, floor = latency(tools, env, "can", rate), latency(tools, env, "socketpair", rate)
            results["latency"] += [hub_lat, floor]
            hub_lat["p50_ratio_to_socketpair"] = round(hub_lat["p50_us"] / max(floor["p50_us"], 0.01), 1)
    finally:
        hub.terminate()
        hub.wait()
    spin_dir = Path(tempfile.mkdtemp(prefix="ucan-bench-spin-", dir="/tmp"))
    hub, env = start_hub(build, spin_dir, "-s", str(SPIN_US))
    try:
        for rate in LATENCY_RATES:
            spun = latency(tools, env, "can", rate)
            floor = next(r for r in results["latency"] if r["mode"] == "socketpair" and r["rate"] == rate)
            spun.update(mode=f"can-spin{SPIN_US}",
                        p50_ratio_to_socketpair=round(spun["p50_us"] / max(floor["p50_us"], 0.01), 1))
            results["latency"].append(spun)
    finally:
        hub.terminate()
        hub.wait()
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
