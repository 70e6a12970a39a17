#!/usr/bin/env python3
"""Instructions per frame of zenoh-node's C path (make bench-callgrind, part of
make bench): a deterministic cost, unlike times on a shared machine.

The release bridge runs under valgrind --tool=callgrind with the userspace hub,
zenohd on loopback and zn-capture, three times for the same wall time: idle,
FRAMES frames CAN -> Zenoh (can-load, one bus, paced), FRAMES commands
Zenoh -> CAN (zn-flood). Per frame: callgrind's inclusive counts of the node's
functions give each stage of the C path: CAN read (the port + the preload's
message from the hub), the component's own code (queue, encode, batching),
put (the Rust Zenoh port and the zenoh crate, on the calling thread), the
command path; and the whole process minus the idle run gives everything a
frame costs in user space, Zenoh's runtime threads included. Kernel
instructions are not counted (callgrind sees user space only; bench-bridge
reports the kernel's share of the CPU time). Each Zenoh transport
(--transports): on the universal one the put queues and Zenoh's transmit
task writes; on the low-latency one the put writes the link itself.

Each transport is measured --runs times (default 5) and each stage counts with
its median: the process's count varies by up to ~4 % between runs of the
same build (how many frames the transmit task's wakeups find, Zenoh's timers),
the C stages by a few instructions. callgrind.md gives the runs' range beside
the medians. Writes callgrind.json and callgrind.md into --out; with --record
appends one line per run to docs/callgrind-history.csv (commit, date, medians
on the universal transport, the default), so the cost is tracked across
commits. Loopback only, bounded."""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench.rig import Rig, Router, candump, start_bridge, stop, transport_args, zn_capture
from canbench.runkeys import open_session

from .common import REPO, add_tool_arguments, run_id_and_output
from .stamps import candump_stamps, zenoh_stamps

FRAMES = 5000
RATE = 1000  # frames/s: slow enough for the bridge under valgrind (about 50x slower) to keep up
HISTORY = REPO / "docs" / "callgrind-history.csv"
# stage -> (function whose inclusive count it is, the run it is divided over); the port's burst
# calls since they replaced the per-frame ones (ecfab0d), the per-frame names for older builds
STAGES = {
    "can_read": ("zn_can_receive_burst|zn_can_receive", "rx"),
    "put": ("zn_put", "rx"),
    "command": ("zn_tx_on_command", "tx"),
    "can_write": ("zn_can_send_burst|zn_can_transmit", "tx"),
}
# the component's own code: self counts of the functions in these files (inlined code stays in its file)
COMPONENT_DIR = "components/zenoh-node/src/"  # every source file of the component, whatever its name


def annotate(callgrind_out: Path, inclusive: bool) -> list[tuple[int, str, str]]:
    """(count, file, function) per function, from callgrind_annotate."""
    text = subprocess.run(["callgrind_annotate", f"--inclusive={'yes' if inclusive else 'no'}", "--threshold=100",
                           str(callgrind_out)], capture_output=True, text=True, check=True).stdout
    rows = []
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+\([^)]*\)\s+(\S+):(\S+)", line)
        if m:
            rows.append((int(m.group(1).replace(",", "")), m.group(2), m.group(3).split("'")[0]))
    return rows


def counts_of(callgrind_out: Path) -> dict[str, int]:
    """Inclusive count per function name, plus "<component>": self counts of the component's files."""
    counts: dict[str, int] = {}
    for n, _, fn in annotate(callgrind_out, inclusive=True):
        counts[fn] = counts.get(fn, 0) + n
    counts["<component>"] = sum(n for n, file, _ in annotate(callgrind_out, inclusive=False)
                                if COMPONENT_DIR in file)
    return counts


def program_total(callgrind_out: Path) -> int:
    for line in callgrind_out.read_text().splitlines():
        if line.startswith("totals:") or line.startswith("summary:"):
            return int(line.split()[1])
    raise ValueError(f"{callgrind_out}: no totals")


TRANSPORTS = ("universal", "low-latency")


def run(args, work: Path, rx_frames: int, tx_frames: int, low_latency: bool) -> tuple[dict[str, int], int]:
    """One bridge under callgrind for FRAMES / RATE seconds of load (or idle): inclusive counts and total."""
    rig = Rig(Path(args.ucan_build), work)
    env, spawn, procs = rig.env, rig.spawn, rig.procs
    try:
        rig.hub.start(["vcan0"])
        router_args, bridge_args = transport_args(low_latency)
        router = Router(args.zenohd)
        endpoint = router.endpoint
        procs.add(router.start(*router_args))
        session = open_session(endpoint)
        zn_out, can_out = work / "zenoh.tsv", work / "can.log"
        capture = zn_capture(procs, args.zn_capture, endpoint, "vehicle/can/rx", zn_out, session, "bench/capture")
        dump = candump(procs, env, "vcan0", can_out)
        out = work / "callgrind.out"
        bridge = start_bridge(procs, ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", args.bridge,
                                      "--router", endpoint, "--can", "vcan0", "--publish-period-ms", "0",
                                      *bridge_args],
                              env, work / "bridge.log", session, "vehicle/can/bridges/**", timeout=180)
        t0 = time.monotonic()
        if rx_frames:
            spawn([args.can_load, "send", "vcan0", "100", RATE, rx_frames], env=env,
                  stdout=subprocess.DEVNULL).wait()
        if tx_frames:
            spawn([args.zn_flood, "--connect", endpoint, "--key", "vehicle/can/tx", "--count", tx_frames,
                   "--rate", RATE, "--stamp-data", "--id", "321"], stdout=subprocess.DEVNULL).wait()
        end = time.monotonic() + 120
        while time.monotonic() < end and (len(zenoh_stamps(zn_out, 0x100)) < rx_frames
                                          or len(candump_stamps(can_out, 0x321)) < tx_frames):
            time.sleep(0.2)  # the bridge under valgrind works off its backlog; bounded
        rx, tx = len(zenoh_stamps(zn_out, 0x100)), len(candump_stamps(can_out, 0x321))
        # the idle run lasts as long as a loaded one: Zenoh's timers cost the same in both
        idle_left = FRAMES / RATE - (time.monotonic() - t0)
        if idle_left > 0:
            time.sleep(idle_left)  # a duration to measure, not a synchronisation
        stop(bridge)
        session.close()
        if rx != rx_frames or tx != tx_frames:
            sys.exit(f"bench-callgrind: the bridge forwarded {rx} of {rx_frames} frames to Zenoh and {tx} of "
                     f"{tx_frames} commands to CAN:\n" + (work / "bridge.log").read_text()[-2000:])
        stop(dump)
        stop(capture, close_stdin=True)
        return counts_of(out), program_total(out)
    finally:
        rig.close()


def measure(args, low_latency: bool) -> dict[str, int]:
    """Instructions per frame by stage on one Zenoh transport."""
    runs = {}
    for name, rx, tx in (("idle", 0, 0), ("rx", FRAMES, 0), ("tx", 0, FRAMES)):
        with tempfile.TemporaryDirectory(prefix="bench-callgrind-") as tmp:
            runs[name] = run(args, Path(tmp), rx, tx, low_latency)
    per_frame = {}
    for stage, (names, direction) in STAGES.items():
        counts = runs[direction][0]
        fn = next((name for name in names.split("|") if name in counts), None)
        if fn is None:
            sys.exit(f"bench-callgrind: no callgrind count for {names} (symbols stripped?)")
        per_frame[stage] = round(counts[fn] / FRAMES)
    if not runs["rx"][0]["<component>"]:
        sys.exit(f"bench-callgrind: no instructions attributed to {COMPONENT_DIR}: {args.bridge} lacks debug info")
    per_frame["component_rx"] = round(runs["rx"][0]["<component>"] / FRAMES)
    per_frame["component_tx"] = round(runs["tx"][0]["<component>"] / FRAMES)
    idle_total = runs["idle"][1]
    per_frame["process_rx"] = round((runs["rx"][1] - idle_total) / FRAMES)
    per_frame["process_tx"] = round((runs["tx"][1] - idle_total) / FRAMES)
    return per_frame


def measure_runs(args, low_latency: bool, runs: int) -> tuple[dict[str, int], dict[str, list[int]]]:
    """Per stage: the median over `runs` measurements, and every run's count."""
    each = [measure(args, low_latency) for _ in range(runs)]
    counts = {stage: [m[stage] for m in each] for stage in each[0]}
    return {stage: round(statistics.median(c)) for stage, c in counts.items()}, counts


def git_commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True).stdout.strip() or "unknown"
    except FileNotFoundError:  # no git (the bench container): make passes BENCH_COMMIT
        return "unknown"


def spread(measured: tuple[dict[str, int], dict[str, list[int]]], stage: str) -> str:
    medians, each = measured
    low, high = min(each[stage]), max(each[stage])
    return f"{medians[stage]}" + (f" [{low}-{high}]" if low != high else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--record", action="store_true", help=f"append this run to {HISTORY.relative_to(REPO)}")
    ap.add_argument("--transports", default=",".join(TRANSPORTS),
                    help="Zenoh transports to measure (the history records the universal one)")
    ap.add_argument("--runs", type=int, default=5, help="measurements per transport; each stage counts with "
                    "their median (default 5)")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs: at least 1")
    transports = args.transports.split(",")
    if set(transports) - set(TRANSPORTS) or TRANSPORTS[0] not in transports:
        ap.error(f"--transports: {TRANSPORTS[0]} and optionally {TRANSPORTS[1]}")
    run_id, out = run_id_and_output(args)
    measured = {t: measure_runs(args, t == "low-latency", args.runs) for t in transports}
    by_transport = {t: medians for t, (medians, _) in measured.items()}
    commit = os.environ.get("BENCH_COMMIT") or git_commit()
    ipf = by_transport[TRANSPORTS[0]]
    result = {"frames": FRAMES, "rate": RATE, "runs": args.runs, "instructions_per_frame": ipf,
              "by_transport": by_transport, "runs_by_transport": {t: each for t, (_, each) in measured.items()},
              "run_id": run_id, "commit": commit}
    (out / "callgrind.json").write_text(json.dumps(result, indent=1))
    md = ["| stage | what | " + " | ".join(f"instructions per frame ({t}): median [range]" for t in transports)
          + " |", "|---|---|" + "---|" * len(transports)]
    what = {stage: fn for stage, (fn, _) in STAGES.items()}
    what.update(component_rx=f"self: {COMPONENT_DIR}*.c in the CAN -> Zenoh run",
                component_tx=f"self: {COMPONENT_DIR}*.c in the Zenoh -> CAN run",
                process_rx="whole process, CAN -> Zenoh run minus idle run",
                process_tx="whole process, Zenoh -> CAN run minus idle run")
    md += [f"| {stage} | {what[stage]} | " + " | ".join(spread(measured[t], stage) for t in transports) + " |"
           for stage in ipf]
    text = (f"callgrind {run_id} at {commit}: {FRAMES} frames each way at {RATE} frames/s, medians of {args.runs} "
            "runs\n\n" + "\n".join(md))
    (out / "callgrind.md").write_text(text + "\n")
    print(text)
    if args.record:
        new = not HISTORY.exists()
        with open(HISTORY, "a") as f:
            if new:
                f.write("run_id,commit," + ",".join(ipf) + "\n")
            f.write(f"{run_id},{commit}," + ",".join(str(v) for v in ipf.values()) + "\n")
        print(f"appended to {HISTORY.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
