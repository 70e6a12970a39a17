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
import sys
import tempfile
import time
from pathlib import Path

from canbench.rig import Rig, Router, start_bridge, zn_capture
from canbench.runkeys import open_session

from .common import add_rig_arguments


def memory(pid: int) -> dict:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "RssAnon", "Threads"):
            fields[key] = int(value.split()[0])
    return fields


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_rig_arguments(ap)
    ap.add_argument("--duration", type=float, default=300)
    ap.add_argument("--restart-every", type=float, default=0, help="seconds between router restarts (0: none)")
    ap.add_argument("--frames-per-ms", type=int, default=1)
    ap.add_argument("--out", help="JSON file for the samples")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="memory-probe-") as tmp:
        work = Path(tmp)
        rig = Rig(Path(args.ucan_build), work)
        env, procs = rig.env, rig.procs
        try:
            rig.hub.start(["vcan0"])
            router = Router(args.zenohd)
            router.start()
            session = open_session(router.endpoint)
            zn_capture(procs, args.zn_capture, router.endpoint, "vehicle/can/**", Path("/dev/null"), session,
                       "probe/capture")
            bridge = start_bridge(procs, [args.bridge, "--router", router.endpoint, "--can", "vcan0"], env,
                                  work / "bridge.log", session, "vehicle/can/bridges/**")
            session.close()
            frames = int(args.duration * 1000 * args.frames_per_ms)
            gen = procs.spawn(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "1",
                               "-c", args.frames_per_ms, "-n", frames], env=env)
            t0 = time.monotonic()
            next_restart = args.restart_every or float("inf")
            samples = []
            while time.monotonic() - t0 < args.duration and gen.poll() is None:
                t = time.monotonic() - t0
                if t >= next_restart:
                    router.stop()
                    router.start()
                    next_restart += args.restart_every
                m = memory(bridge.pid)
                samples.append((round(t, 1), m["RssAnon"], m["VmRSS"], m["Threads"]))
                if len(samples) % 30 == 1:
                    print(f"t={t:6.0f} s RssAnon {m['RssAnon'] / 1024:6.2f} MiB VmRSS {m['VmRSS'] / 1024:6.2f} MiB "
                          f"threads {m['Threads']}", flush=True)
                time.sleep(1)  # sampling period
            if args.out:
                Path(args.out).write_text(json.dumps({"args": vars(args), "samples": samples}))
        finally:
            rig.close()
            if "router" in locals():
                router.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
