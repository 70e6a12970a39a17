#!/usr/bin/env python3
"""Wakeups, CPU time and syscall batching per frame of one zenoh-node at fixed loads
(python -m bench.wakeups; a quick host measurement next to make bench, docs/benchmark.md).

One bus on the userspace hub, zenohd on loopback, one bridge. CAN -> Zenoh: can-load sends
RATES frames/s (10, 50 and 90 % of a 1 Mbit/s bus of 8-byte frames) for LOAD_S seconds,
zn-capture counts them on Zenoh; immediate mode and batching mode (BATCH_MS). Zenoh -> CAN:
commands of COMMAND_FRAMES frames each at TX_RATE frames/s from one Zenoh session, can-load
counts them on the bus. Per run, over the bridge process (all its threads): context switches
per frame (voluntary + involuntary, /proc/<pid>/task/*/status), CPU time per frame (utime +
stime) and its kernel share, and whether every frame arrived. Compare two builds by running it
twice (--bridge, --ucan-build: the bridge and the hub/preload it runs on).

Loopback only; every load is bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench import wire
from canbench.rig import Rig, Router, start_bridge, zn_capture
from canbench.runkeys import open_session

from .bridge import count_frames
from .common import add_tool_arguments, cpu_split_s, machine_line, run_id_and_output, settle

RATES = (900, 4500, 8100)  # frames/s: 10, 50, 90 % of a saturated 1 Mbit/s bus of 8-byte frames
LOAD_S = 2.0
BATCH_MS = 10
TX_RATE = 8000  # frames/s Zenoh -> CAN
COMMAND_FRAMES = 16  # frames per command Zenoh -> CAN
SETTLE_S = 10.0


def ctx_switches(pid: int) -> int:
    """Voluntary + involuntary context switches of every thread of a process so far."""
    total = 0
    for status in Path(f"/proc/{pid}/task").glob("*/status"):
        try:
            for line in status.read_text().splitlines():
                if line.startswith(("voluntary_ctxt_switches:", "nonvoluntary_ctxt_switches:")):
                    total += int(line.split()[1])
        except OSError:  # a thread that just ended
            pass
    return total


class Run(Rig):
    def __init__(self, args, workdir: Path):
        super().__init__(Path(args.ucan_build), workdir)
        self.args = args

    def one(self, direction: str, mode: str, rate: int) -> dict:
        self.hub.start(["vcan0"])
        router = Router(self.args.zenohd)
        self.procs.add(router.start())
        endpoint = router.endpoint
        session = open_session(endpoint)
        capture = self.workdir / "zenoh.tsv"
        if direction == "can-to-zenoh":
            zn_capture(self.procs, self.args.zn_capture, endpoint, "vehicle/can/**", capture, session,
                       "bench/capture")
        period = str(BATCH_MS) if mode == "batching" else "0"
        bridge = start_bridge(self.procs, [self.args.bridge, "--router", endpoint, "--can", "vcan0",
                                           "--publish-period-ms", period], self.env, self.workdir / "bridge.log",
                              session, "vehicle/can/bridges/*/vcan0/**")
        frames = int(rate * LOAD_S)
        if direction == "zenoh-to-can":
            frames -= frames % COMMAND_FRAMES
        user0, sys0 = cpu_split_s(bridge.pid)
        ctx0 = ctx_switches(bridge.pid)
        if direction == "can-to-zenoh":
            self.procs.spawn([self.args.can_load, "send", "vcan0", "100", rate, frames], env=self.env,
                             stdout=subprocess.DEVNULL).wait()
            received = settle(lambda: count_frames(capture), frames, SETTLE_S, 0.1)
        else:
            before = self.hub.bound_sockets()
            reader = self.procs.spawn([self.args.can_load, "count", "vcan0", frames, 1000], env=self.env,
                                      stdout=subprocess.PIPE, text=True)
            self.hub.wait_bound(before + 1)
            pub = session.declare_publisher("vehicle/can/tx")
            gap = COMMAND_FRAMES / rate
            start = time.monotonic()
            for k in range(frames // COMMAND_FRAMES):
                payload = b"".join(wire.encode(wire.Frame(0x200 + i, 8, (k * COMMAND_FRAMES + i).to_bytes(8, "little")))
                                   for i in range(COMMAND_FRAMES))
                due = start + k * gap
                if due > time.monotonic():
                    time.sleep(due - time.monotonic())  # the load's pace, not a synchronisation
                pub.put(payload)
            counted = json.loads(reader.communicate(timeout=SETTLE_S + 5)[0])  # stops after 1 s idle
            received = counted["frames"]
            pub.undeclare()
        user1, sys1 = cpu_split_s(bridge.pid)
        ctx = ctx_switches(bridge.pid) - ctx0
        self.procs.close()
        session.close()
        cpu = (user1 - user0) + (sys1 - sys0)
        return {"direction": direction, "mode": mode, "rate": rate, "frames": frames, "received": received,
                "lossless": received == frames, "ctx_per_frame": round(ctx / max(received, 1), 3),
                "cpu_us_per_frame": round(cpu / max(received, 1) * 1e6, 2),
                "kernel_share": round((sys1 - sys0) / cpu, 2) if cpu else None}


def table(results: list[dict]) -> str:
    rows = ["| direction | mode | frames/s | received | context switches per frame | CPU µs per frame | "
            "of it in the kernel |", "|---|---|---|---|---|---|---|"]
    for r in results:
        rows.append(f"| {r['direction']} | {r['mode']} | {r['rate']} | {r['received']}/{r['frames']} | "
                    f"{r['ctx_per_frame']} | {r['cpu_us_per_frame']} | {r['kernel_share']} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--rates", default=",".join(map(str, RATES)))
    ap.add_argument("--label", default="", help="what build this is (printed with the table)")
    args = ap.parse_args()
    run_id, out = run_id_and_output(args)
    results = []
    plan = [("can-to-zenoh", mode, int(rate)) for mode in ("immediate", "batching")
            for rate in args.rates.split(",")] + [("zenoh-to-can", "immediate", TX_RATE)]
    for direction, mode, rate in plan:
        with tempfile.TemporaryDirectory(prefix="bench-wakeups-") as tmp:
            run = Run(args, Path(tmp))
            try:
                results.append(run.one(direction, mode, rate))
            finally:
                run.close()
        print(json.dumps(results[-1]), flush=True)
    text = f"wakeups {run_id} {args.label} ({machine_line()})\n\n" + table(results)
    (out / "wakeups.json").write_text(json.dumps({"run_id": run_id, "label": args.label, "results": results},
                                                 indent=1))
    (out / "wakeups.md").write_text(text + "\n")
    print(text)
    return 0 if all(r["lossless"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
