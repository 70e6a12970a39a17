#!/usr/bin/env python3
"""Wakeups, CPU time and syscall batching per frame of one zenoh-node at fixed loads
(python -m bench.wakeups; a quick host measurement next to make bench, docs/benchmark.md).

One bus on the userspace hub, zenohd on loopback, one bridge. CAN -> Zenoh: can-load sends
RATES frames/s (10, 50 and 90 % of a 1 Mbit/s bus of 8-byte frames) for LOAD_S seconds,
zn-capture counts them on Zenoh; immediate mode and batching mode (BATCH_MS). Zenoh -> CAN:
commands of COMMAND_FRAMES frames each at TX_RATE frames/s from one Zenoh session, can-load
counts them on the bus (bench.bridge also runs it in batching mode: a command per BATCH_MS
holding that period's frames, as a bridge in batching mode publishes them). Per run, over the
bridge process (all its threads): context switches per frame (voluntary + involuntary,
/proc/<pid>/task/*/status), CPU time per frame and its kernel share, and whether every frame
arrived. Compare two builds by running it
twice (--bridge, --ucan-build: the bridge and the hub/preload it runs on).

--can-side: the CAN side alone, zenoh-node-memzenoh (the bridge on the real CAN port with Zenoh
replaced by the in-memory recorder, built with the unit tests, no cargo): no router, what was
published read from the bridge's final stats; CAN -> Zenoh at RATES and a near-saturated
unthrottled bus (CAN_SIDE_FAST), both modes. --strace adds syscalls per frame (strace -c
attached for the load, which slows the bridge: its CPU numbers are then not comparable).

CPU time is the threads' run time from /proc/<pid>/task/*/schedstat (nanoseconds; the tick-based
utime/stime only split it into user and kernel).

Loopback only; every load is bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench import wire
from canbench.rig import Rig, Router, start_bridge, stop, transport_args, zn_capture
from canbench.runkeys import open_session

from .common import add_tool_arguments, cpu_split_s, ctx_switches, machine_line, run_id_and_output, run_ns, settle
from .stamps import count_frames

RATES = (900, 4500, 8100)  # frames/s: 10, 50, 90 % of a saturated 1 Mbit/s bus of 8-byte frames
CAN_SIDE_FAST = 50000  # frames/s: an unthrottled userspace bus, frames queue between wakeups
LOAD_S = 3.0
BATCH_MS = 10
TX_RATE = 8000  # frames/s Zenoh -> CAN
COMMAND_FRAMES = 16  # frames per command Zenoh -> CAN
SETTLE_S = 10.0


class Probe:
    """CPU, kernel share and context switches of a process between start() and end()."""

    def __init__(self, pid: int):
        self.pid = pid
        self.start = (run_ns(pid), *cpu_split_s(pid))
        self.start_threads = ctx_switches(pid)

    def end(self, frames: int) -> dict:
        ns, user, system = (a - b for a, b in zip((run_ns(self.pid), *cpu_split_s(self.pid)), self.start,
                                                  strict=True))
        threads = {name: n - self.start_threads.get(name, 0) for name, n in ctx_switches(self.pid).items()}
        per_frame = {name: round(n / max(frames, 1), 3) for name, n in sorted(threads.items(), key=lambda kv: -kv[1])
                     if n}
        return {"ctx_per_frame": round(sum(threads.values()) / max(frames, 1), 3), "ctx_per_frame_by_thread": per_frame,
                "cpu_us_per_frame": round(ns / max(frames, 1) / 1e3, 2),
                "kernel_share": round(system / (user + system), 2) if user + system else None}


def strace_counts(path: Path) -> dict[str, int]:
    """Calls per syscall from strace -c output (the total row left out)."""
    calls = {}
    for line in path.read_text().splitlines():
        f = line.split()
        if len(f) >= 5 and f[-1].isidentifier() and f[-1] != "total" and f[3].isdigit():
            calls[f[-1]] = int(f[3])
    return calls


class Run(Rig):
    def __init__(self, args, workdir: Path):
        super().__init__(Path(args.ucan_build), workdir)
        self.args = args
        # Zenoh's thread pools of the bridge alone (zenoh-runtime: ZENOH_RUNTIME), never the router's
        self.bridge_env = {**self.env, **({"ZENOH_RUNTIME": args.zenoh_runtime} if args.zenoh_runtime else {})}

    def one(self, direction: str, mode: str, rate: int, low_latency: bool = False) -> dict:
        """One run; low_latency: the bridge and the router on Zenoh's low-latency transport."""
        self.hub.start(["vcan0"])
        router_args, bridge_args = transport_args(low_latency)
        router = Router(self.args.zenohd)
        self.procs.add(router.start(*router_args))
        endpoint = router.endpoint
        session = open_session(endpoint)
        capture = self.workdir / "zenoh.tsv"
        if direction == "can-to-zenoh":
            zn_capture(self.procs, self.args.zn_capture, endpoint, "vehicle/can/**", capture, session,
                       "bench/capture")
        period = str(BATCH_MS) if mode == "batching" else "0"
        bridge = start_bridge(self.procs, [self.args.bridge, "--router", endpoint, "--can", "vcan0",
                                           "--publish-period-ms", period, *bridge_args],
                              self.bridge_env, self.workdir / "bridge.log", session, "vehicle/can/bridges/*/vcan0/**")
        frames = int(rate * LOAD_S)
        command_frames = max(1, rate * BATCH_MS // 1000) if mode == "batching" else COMMAND_FRAMES
        if direction == "zenoh-to-can":
            frames -= frames % command_frames
        probe = Probe(bridge.pid)
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
            gap = command_frames / rate
            start = time.monotonic()
            for k in range(frames // command_frames):
                payload = b"".join(wire.encode(wire.Frame(0x200 + i % 16, 8,
                                                          (k * command_frames + i).to_bytes(8, "little")))
                                   for i in range(command_frames))
                due = start + k * gap
                if due > time.monotonic():
                    time.sleep(due - time.monotonic())  # the load's pace, not a synchronisation
                pub.put(payload)
            counted = json.loads(reader.communicate(timeout=SETTLE_S + 5)[0])  # stops after 1 s idle
            received = counted["frames"]
            pub.undeclare()
        measured = probe.end(received)
        self.procs.close()
        session.close()
        return {"direction": direction, "mode": mode, "transport": "low-latency" if low_latency else "universal",
                "rate": rate, "frames": frames, "received": received, "lossless": received == frames, **measured}

    def can_side(self, mode: str, rate: int, strace: bool) -> dict:
        """CAN -> Zenoh into zenoh-node-memzenoh: the reader, the queue and the publisher, no Zenoh."""
        self.hub.start(["vcan0"])
        log = self.workdir / "bridge.log"
        period = str(BATCH_MS) if mode == "batching" else "0"
        with open(log, "w") as out:
            bridge = self.procs.spawn([self.args.bridge, "--can", "vcan0", "--publish-period-ms", period],
                                      env=self.env, stdout=out, stderr=subprocess.STDOUT)
        self.hub.wait_bound(1)
        tracer = None
        if strace:
            tracer = subprocess.Popen(["strace", "-f", "-c", "-o", str(self.workdir / "strace.txt"), "-p",
                                       str(bridge.pid)], stderr=subprocess.DEVNULL)
            time.sleep(1.0)  # strace attaches to every thread; no signal says it has
        frames = int(rate * LOAD_S)
        probe = Probe(bridge.pid)
        self.procs.spawn([self.args.can_load, "send", "vcan0", "100", rate, frames], env=self.env,
                         stdout=subprocess.DEVNULL).wait()
        time.sleep(4 * BATCH_MS / 1000)  # a duration: the last period's frames are read
        measured = probe.end(frames)
        if tracer:
            tracer.send_signal(signal.SIGINT)
            tracer.wait()
        stop(bridge)
        m = re.search(r'"published_frames": (\d+)', log.read_text())
        received = int(m.group(1)) if m else 0
        row = {"direction": "can-to-zenoh (CAN side)", "mode": mode, "rate": rate, "frames": frames,
               "received": received, "lossless": received == frames, **measured}
        if tracer:
            calls = strace_counts(self.workdir / "strace.txt")
            row["syscalls_per_frame"] = round(sum(calls.values()) / frames, 3)
            row["syscalls"] = {k: round(v / frames, 3) for k, v in sorted(calls.items(), key=lambda kv: -kv[1])[:4]}
        return row


def in_fresh_rig(args, job) -> dict:
    """job(run) in a rig of its own, its result printed as a JSON line."""
    with tempfile.TemporaryDirectory(prefix="bench-wakeups-", dir="/tmp") as tmp:  # short: unix socket path
        run = Run(args, Path(tmp))
        try:
            result = job(run)
        finally:
            run.close()
    print(json.dumps(result), flush=True)
    return result


def measure(args, direction: str, mode: str, rate: int, low_latency: bool = False) -> dict:
    """One run of the bridge with Zenoh (Run.one) in a rig of its own."""
    return in_fresh_rig(args, lambda run: run.one(direction, mode, rate, low_latency))


def table(results: list[dict]) -> str:
    rows = ["| direction | mode | Zenoh transport | frames/s | received | context switches per frame | "
            "by thread (top 4) | CPU µs per frame | of it in the kernel | syscalls per frame |", "|" + "---|" * 10]
    for r in results:
        calls = (f"{r['syscalls_per_frame']} ({', '.join(f'{k} {v}' for k, v in r['syscalls'].items())})"
                 if "syscalls" in r else "")
        threads = ", ".join(f"{name} {n}" for name, n in list(r["ctx_per_frame_by_thread"].items())[:4])
        rows.append(f"| {r['direction']} | {r['mode']} | {r.get('transport', 'universal')} | {r['rate']} | "
                    f"{r['received']}/{r['frames']} | "
                    f"{r['ctx_per_frame']} | {threads} | {r['cpu_us_per_frame']} | {r['kernel_share']} | {calls} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--rates", default=",".join(map(str, RATES)))
    ap.add_argument("--label", default="", help="what build this is (printed with the table)")
    ap.add_argument("--can-side", action="store_true", help="--bridge is zenoh-node-memzenoh: the CAN side alone")
    ap.add_argument("--strace", action="store_true", help="--can-side: syscalls per frame (strace -c)")
    ap.add_argument("--zenoh-runtime", default="", help="ZENOH_RUNTIME for the bridge only, e.g. "
                    "'(rx: (handover: tx), app: (handover: tx), net: (handover: tx), acc: (handover: tx))'")
    ap.add_argument("--transports", default="universal", help="Zenoh transports of the bridge and its router: "
                    "universal, low-latency or both (comma-separated; docs/bridge.md)")
    ap.add_argument("--modes", default="immediate,batching,zenoh-to-can",
                    help="which runs: CAN -> Zenoh immediate and batching, Zenoh -> CAN (comma-separated)")
    args = ap.parse_args()
    run_id, out = run_id_and_output(args)
    results = []
    rates = [int(rate) for rate in args.rates.split(",")]
    modes = args.modes.split(",")
    unknown = set(modes) - {"immediate", "batching", "zenoh-to-can"}
    if unknown:
        ap.error(f"--modes: unknown {', '.join(sorted(unknown))}")
    transports = args.transports.split(",")
    if set(transports) - {"universal", "low-latency"}:
        ap.error(f"--transports: unknown {', '.join(sorted(set(transports) - {'universal', 'low-latency'}))}")
    can_modes = [m for m in ("immediate", "batching") if m in modes]
    if args.can_side:  # no Zenoh: one run per mode and rate, whatever the transports
        for mode in can_modes:
            for rate in rates + [CAN_SIDE_FAST]:
                results.append(in_fresh_rig(args, lambda run, mode=mode, rate=rate: run.can_side(mode, rate,
                                                                                                 args.strace)))
    else:
        plan = [("can-to-zenoh", mode, rate) for mode in can_modes for rate in rates]
        if "zenoh-to-can" in modes:
            plan.append(("zenoh-to-can", "immediate", TX_RATE))
        for low_latency in [t == "low-latency" for t in transports]:
            for direction, mode, rate in plan:
                results.append(measure(args, direction, mode, rate, low_latency))
    text = f"wakeups {run_id} {args.label} ({machine_line()})\n\n" + table(results)
    (out / "wakeups.json").write_text(json.dumps({"run_id": run_id, "label": args.label, "results": results},
                                                 indent=1))
    (out / "wakeups.md").write_text(text + "\n")
    print(text)
    return 0 if all(r["lossless"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
