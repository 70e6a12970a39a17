#!/usr/bin/env python3
"""Memory probe for zenoh-node (docs/faults.md, "Soak"): the bridge on the host
with the userspace hub, zenohd on loopback and a subscriber, a steady CAN load
(cangen, paced), optionally a router restart every --restart-every seconds;
the bridge's RssAnon/VmRSS/threads are sampled once a second. Tells a leak
(growth per restart or per frame) from warm-up (growth that stops) in minutes,
without the compose soak. Loopback only, bounded by --duration."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench.runkeys import open_session, wait_token

from .common import REPO, free_port, stop


def memory(pid: int) -> dict:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "RssAnon", "Threads"):
            fields[key] = int(value.split()[0])
    return fields


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--bridge", default=str(REPO / "build" / "firmware" / "zenoh-node"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))
    ap.add_argument("--duration", type=float, default=300)
    ap.add_argument("--restart-every", type=float, default=0, help="seconds between router restarts (0: none)")
    ap.add_argument("--frames-per-ms", type=int, default=1)
    ap.add_argument("--out", help="JSON file for the samples")
    args = ap.parse_args()
    build = Path(args.ucan_build)
    with tempfile.TemporaryDirectory(prefix="memory-probe-") as tmp:
        work = Path(tmp)
        env = dict(os.environ, UCAN_DIR=tmp, LD_PRELOAD=str(build / "libucan-preload.so"))
        procs: list[subprocess.Popen] = []
        try:
            procs.append(subprocess.Popen([str(build / "ucan-hub"), "-d", tmp, "vcan0"], stderr=subprocess.DEVNULL))
            deadline = time.monotonic() + 10
            while not (work / "hub.sock").exists() and time.monotonic() < deadline:
                time.sleep(0.01)  # the hub's socket file is its readiness
            endpoint = f"tcp/127.0.0.1:{free_port()}"

            def start_router() -> subprocess.Popen:
                return subprocess.Popen([args.zenohd, "--no-multicast-scouting", "-l", endpoint],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            router = start_router()
            session = open_session(endpoint)
            capture = subprocess.Popen([args.zn_capture, "--connect", endpoint, "--key", "vehicle/can/**",
                                        "--ready-token", "probe/capture", "--out", "/dev/null"],
                                       stdin=subprocess.PIPE, stderr=subprocess.DEVNULL)
            procs.append(capture)
            wait_token(session, "probe/capture", 20)
            bridge = subprocess.Popen([args.bridge, "--router", endpoint, "--can", "vcan0"], env=env,
                                      stdout=open(work / "bridge.log", "w"), stderr=subprocess.STDOUT)
            procs.append(bridge)
            wait_token(session, "vehicle/can/bridges/**", 30)
            session.close()
            frames = int(args.duration * 1000 * args.frames_per_ms)
            gen = subprocess.Popen(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "1",
                                    "-c", str(args.frames_per_ms), "-n", str(frames)], env=env)
            procs.append(gen)
            t0 = time.monotonic()
            next_restart = args.restart_every or float("inf")
            samples = []
            while time.monotonic() - t0 < args.duration and gen.poll() is None:
                t = time.monotonic() - t0
                if t >= next_restart:
                    stop(router)
                    router = start_router()
                    next_restart += args.restart_every
                m = memory(bridge.pid)
                samples.append((round(t, 1), m["RssAnon"], m["VmRSS"], m["Threads"]))
                if len(samples) % 30 == 1:
                    print(f"t={t:6.0f} s RssAnon {m['RssAnon'] / 1024:6.2f} MiB VmRSS {m['VmRSS'] / 1024:6.2f} MiB "
                          f"threads {m['Threads']}", flush=True)
                time.sleep(1)  # sampling period
            procs.append(router)
            if args.out:
                Path(args.out).write_text(json.dumps({"args": vars(args), "samples": samples}))
        finally:
            for p in reversed(procs):
                if p.poll() is None:
                    stop(p, close_stdin=p is capture if "capture" in locals() else False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
