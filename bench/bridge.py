#!/usr/bin/env python3
"""Bridge benchmark (make bench-bridge): CAN -> Zenoh and Zenoh -> CAN
forwarding of zenoh-node next to the Python reference bridge (bench/refbridge.py: python-can +
eclipse-zenoh, what a user writes first), in the same run, on the same
machine, same bus (the userspace hub), router (zenohd on loopback) and capture
(zn-capture).

Offered load: 1, 2, 4, 8, 16, 24, 32, 48, 64 buses, each at one saturated 1 Mbit/s bus
(9000 frames/s of 8 bytes) for LOAD_S seconds, from one can-load process
(exactly paced, all buses interleaved); per system the loads go up until the
first one with loss. A zenoh-node instance bridges at most ZN_MAX_BUSES = 8
buses, so more buses run several instances (each its own name and keys), as a
vehicle computer with more buses would. Systems: zenoh-node in immediate mode
(one put per frame) and in batching mode (--publish-period-ms BATCH_MS), the
Python reference.

Zenoh -> CAN, the same loads the other way: zn-flood publishes stamped
commands on every bus's tx key (9000/s per bus, all keys interleaved, one
Zenoh session) and one can-load reader counts them on all buses, checking
that each bus's stamps only rise (no reordering, no duplicates). Systems:
zenoh-node (its publish period batches only CAN -> Zenoh) and the reference.

Per system, direction and load: frames offered, received, lossless or not,
the bridges' CPU time per forwarded frame (utime + stime from /proc, all
instances) and peak RSS (the largest instance).
Ratios zenoh-node / reference are computed within the run; absolute numbers
are only a record of this machine.

Writes bench.json, bench.md (the table README's performance section is
generated from), throughput_can_to_zenoh.png and throughput_zenoh_to_can.png.
Loopback only; every load is bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from canbench import wire
from canbench.capture import iter_zenoh_capture
from canbench.errors import RunError
from canbench.rig import Rig, Router, start_bridge, zn_capture
from canbench.runkeys import open_session

from .common import (
    REPO,
    add_tool_arguments,
    cpu_s,
    cpu_split_s,
    machine_line,
    rss_mib,
    run_id_and_output,
    settle,
)
from .stamps import load_rate, zenoh_stamps

BUS_COUNTS = (1, 2, 4, 8, 16, 24, 32, 48, 64)  # can-load: at most 64 interfaces
BUSES_PER_NODE = 8  # ZN_MAX_BUSES
FRAMES_PER_S = 9000  # ~ one saturated 1 Mbit/s bus of 8-byte frames
LOAD_S = 2.0
BATCH_MS = 10
SYSTEMS = ("zenoh-node", f"zenoh-node-batch{BATCH_MS}", "python-ref")
ZENOH_TO_CAN_SYSTEMS = ("zenoh-node", "python-ref")  # the publish period batches CAN -> Zenoh only
DIRECTIONS = ("can-to-zenoh", "zenoh-to-can")
SETTLE_S = 10.0


def count_frames(path: Path) -> int:
    if not path.exists():
        return 0
    return sum(len(s.payload) // wire.WIRE_SIZE for s in iter_zenoh_capture(path, growing=True))


def bus_keys(prefix: str, group: list[str], direction: str) -> list[str]:
    """A bridge's per-bus keys: <prefix>/rx|tx for one bus, <prefix>/<bus>/rx|tx for several (docs/bridge.md)."""
    return [f"{prefix}/{direction}"] if len(group) == 1 else [f"{prefix}/{bus}/{direction}" for bus in group]


def sustained_fps(frames: int, first_send_ns: int, last_receive_ns: int) -> int | None:
    """Frames over first send to last receive: a backlog worked off after the load counts at the
    rate it was really carried."""
    span_s = (last_receive_ns - first_send_ns) / 1e9
    return round(frames / span_s) if frames and span_s > 0 else None


class Bench(Rig):
    """One measurement: a fresh hub with the buses, zenohd, the bridge instances of one system."""

    def __init__(self, args, workdir: Path):
        super().__init__(Path(args.ucan_build), workdir)
        self.args = args
        # Zenoh's thread pools of zenoh-node alone (--zenoh-runtime), never the router's, the load's or the reference's
        self.bridge_env = {**self.env, **({"ZENOH_RUNTIME": args.zenoh_runtime} if args.zenoh_runtime else {})}

    def run_one(self, system: str, buses: int, direction: str = "can-to-zenoh") -> dict:
        names = [f"vcan{i}" for i in range(buses)]
        self.hub.start(names)
        router = Router(self.args.zenohd)
        self.procs.add(router.start())
        endpoint = router.endpoint
        session = open_session(endpoint)
        capture_file = self.workdir / f"{system}-{buses}.tsv"
        if direction == "can-to-zenoh":
            zn_capture(self.procs, self.args.zn_capture, endpoint, "vehicle/can/**", capture_file, session,
                       "bench/capture")
        per_node = BUSES_PER_NODE if system.startswith("zenoh-node") else buses
        groups = [names[k:k + per_node] for k in range(0, buses, per_node)]
        bridges = []
        for k, group in enumerate(groups):
            if system.startswith("zenoh-node"):
                period = system.removeprefix("zenoh-node").removeprefix("-batch") or "0"
                cmd = [self.args.bridge, "--router", endpoint, "--can", ",".join(group), "--publish-period-ms",
                       period, "--name", f"zenoh-node-{k}"]
            else:
                cmd = [sys.executable, "-m", "bench.refbridge", "--router", endpoint, "--can", ",".join(group)]
            try:
                env = self.bridge_env if system.startswith("zenoh-node") else self.env
                bridges.append(start_bridge(self.procs, cmd, env, self.workdir / f"{system}-{k}.log", session,
                                            f"vehicle/can/bridges/*/{group[0]}/**", cwd=REPO))
            except RunError as e:
                sys.exit(f"{system} with {buses} buses did not come up: {e}")
        per_bus = int(FRAMES_PER_S * LOAD_S)
        offered = per_bus * buses
        sys0 = sum(cpu_split_s(b.pid)[1] for b in bridges)
        cpu0 = sum(cpu_s(b.pid) for b in bridges)
        peak_rss = 0.0

        def sample_rss() -> None:
            nonlocal peak_rss
            peak_rss = max([peak_rss] + [rss_mib(b.pid) for b in bridges])

        if direction == "can-to-zenoh":
            gen = self.procs.spawn([self.args.can_load, "send", ",".join(names), "100", FRAMES_PER_S, per_bus],
                             env=self.env, stdout=subprocess.PIPE, text=True)
            while gen.poll() is None:
                sample_rss()
                time.sleep(0.05)  # sampling period of the RSS probe
            offered_fps = round(offered / json.loads(gen.stdout.read())["seconds"])
            settle(lambda: count_frames(capture_file), offered, SETTLE_S, 0.1, tick=sample_rss)
        else:  # Zenoh -> CAN: stamped commands on every bus's tx key, one counting reader on all buses
            before = self.hub.bound_sockets()
            reader = self.procs.spawn([self.args.can_load, "count", ",".join(names), offered, 1000], env=self.env,
                                      stdout=subprocess.PIPE, text=True)
            self.hub.wait_bound(before + buses)
            keys = [key for group in groups for key in bus_keys("vehicle/can", group, "tx")]
            gen = self.procs.spawn([self.args.zn_flood, "--connect", endpoint, "--key", ",".join(keys), "--count",
                              per_bus, "--rate", FRAMES_PER_S, "--stamp-data", "--id", "200"],
                             stdout=subprocess.PIPE, text=True)
            while gen.poll() is None:
                sample_rss()
                time.sleep(0.05)  # sampling period of the RSS probe
            if gen.returncode != 0:
                sys.exit(f"zn-flood exited {gen.returncode}")
            offered_fps = load_rate(gen.stdout.read(), offered)
            counted = json.loads(reader.communicate(timeout=SETTLE_S + 5)[0])  # stops after 1 s idle
        cpu = sum(cpu_s(b.pid) for b in bridges) - cpu0
        system_cpu = sum(cpu_split_s(b.pid)[1] for b in bridges) - sys0
        self.procs.close()
        session.close()
        if direction == "can-to-zenoh":
            stamps = zenoh_stamps(capture_file)
            received = count_frames(capture_file)
            delivered = sustained_fps(len(stamps), min(t for t, _ in stamps), max(r for _, r in stamps)) \
                if stamps else None
            in_order = True  # ordering CAN -> Zenoh is the scenarios' business (the oracle)
        else:
            received = counted["frames"]
            delivered = sustained_fps(received, counted["first_stamp_ns"], counted["last_recv_ns"])
            in_order = counted["out_of_order"] == 0
        return {"direction": direction, "system": system, "buses": buses, "offered": offered,
                "delivered_fps": delivered, "offered_fps": offered_fps, "instances": len(bridges),
                "received": received, "lossless": received == offered and in_order,
                "cpu_us_per_frame": round(cpu / max(received, 1) * 1e6, 2),
                "kernel_share": round(system_cpu / cpu, 2) if cpu else None, "peak_rss_mib": round(peak_rss, 1)}

    def cleanup(self) -> None:
        for p in self.procs.procs:
            if p.poll() is None:
                p.kill()
        self.close()


def best_lossless(results: list[dict], system: str) -> int:
    """The highest rate a system carried losslessly, counted only as far as it was sustained
    (a load worked off later as a backlog counts at the rate it was really carried)."""
    return max([min(r["offered_fps"] or 0, r["delivered_fps"] or 0) for r in results
                if r["system"] == system and r["lossless"]], default=0)


def first_loss(results: list[dict], system: str) -> str:
    """Where a system first lost frames, or that it never did (its limit lies beyond the loads offered)."""
    lossy = sorted(r["buses"] for r in results if r["system"] == system and not r["lossless"])
    highest = max((r["buses"] for r in results if r["system"] == system), default=0)
    return f"{lossy[0]} buses" if lossy else f"none up to {highest} buses"


def table(results: list[dict]) -> str:
    rows = ["| direction | system | buses | instances | offered frames/s | received | lossless | delivered frames/s | "
            "CPU µs/frame | of it in the kernel | RSS MiB |", "|" + "---|" * 11]
    for r in sorted(results, key=lambda r: (DIRECTIONS.index(r.get("direction", DIRECTIONS[0])),
                                            SYSTEMS.index(r["system"]), r["buses"])):
        rows.append(f"| {r.get('direction', DIRECTIONS[0])} | {r['system']} | {r['buses']} | {r['instances']} | "
                    f"{r['offered_fps']} | {r['received']}/{r['offered']} | {'yes' if r['lossless'] else 'no'} | "
                    f"{r['delivered_fps']} | {r['cpu_us_per_frame']} | {r['kernel_share']} | {r['peak_rss_mib']} |")
    ref = "python-ref"
    for direction in DIRECTIONS:
        runs = [r for r in results if r.get("direction", DIRECTIONS[0]) == direction]
        if not runs:
            continue
        systems = [s for s in SYSTEMS if any(r["system"] == s for r in runs)]
        best = {s: best_lossless(runs, s) for s in systems}
        by = {(r["system"], r["buses"]): r for r in runs}
        target = " | >= 144000 |" if direction == "can-to-zenoh" else " | |"
        rows += ["", f"| {direction} | " + " | ".join(systems) + " | target |",
                 "|---|" + "---|" * (len(systems) + 1),
                 "| highest lossless frames/s | " + " | ".join(str(best[s]) for s in systems) + target,
                 "| first load with loss | " + " | ".join(first_loss(runs, s) for s in systems) + " | |",
                 "| ... relative to the Python reference | "
                 + " | ".join(f"{best[s] / best[ref]:.1f}x" if best.get(ref) else "-" for s in systems)
                 + " | >= 3x |"]
        ratios = []
        for s in systems:
            common = [(by[(s, n)]["cpu_us_per_frame"], by[(ref, n)]["cpu_us_per_frame"]) for (sys_, n) in by
                      if sys_ == s and (ref, n) in by and by[(s, n)]["lossless"] and by[(ref, n)]["lossless"]]
            ratios.append(f"{statistics.median(a / b for a, b in common):.2f}" if common else "-")
        rows.append("| CPU time per frame relative to the reference (median over loads both forward losslessly) | "
                    + " | ".join(ratios) + " | <= 0.1 |")
        rows.append("| peak RSS MiB (any load) | " + " | ".join(
            str(max([r["peak_rss_mib"] for r in runs if r["system"] == s], default=0)) for s in systems)
            + " | <= 32 |")
    return "\n".join(rows)


def plot(results: list[dict], path: Path, direction: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = [r for r in results if r.get("direction", DIRECTIONS[0]) == direction]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for s in SYSTEMS:
        pts = sorted((r for r in runs if r["system"] == s), key=lambda r: r["buses"])
        if pts:
            ax.plot([r["offered_fps"] or 0 for r in pts], [r["delivered_fps"] or 0 for r in pts], marker="o",
                    label=s)
    top = max((r["offered_fps"] or 0 for r in runs), default=1)
    ax.plot([0, top], [0, top], color="grey", linestyle=":", label="offered")
    ax.set_xlabel(f"offered frames/s ({FRAMES_PER_S} per bus)")
    ax.set_ylabel("frames/s delivered (first send to last receive)")
    ax.set_title(f"{direction} throughput")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_tool_arguments(ap)
    ap.add_argument("--buses", default=",".join(map(str, BUS_COUNTS)))
    ap.add_argument("--directions", default=",".join(DIRECTIONS))
    ap.add_argument("--systems", default=",".join(SYSTEMS), help="which systems (comma-separated; ratios need "
                    "python-ref)")
    ap.add_argument("--zenoh-runtime", default="", help="ZENOH_RUNTIME for zenoh-node only (docs/benchmark.md)")
    ap.add_argument("--update-readme", action="store_true",
                    help="replace README's performance table (between the bench markers) with this run's")
    args = ap.parse_args()
    systems = args.systems.split(",")
    if set(systems) - set(SYSTEMS):
        ap.error(f"--systems: unknown {', '.join(sorted(set(systems) - set(SYSTEMS)))} (known: {', '.join(SYSTEMS)})")
    run_id, out = run_id_and_output(args)
    results = []
    for direction in args.directions.split(","):
        lossy: set[str] = set()  # systems past their first load with loss: no higher load for them
        for buses in [int(b) for b in args.buses.split(",")]:
            for system in SYSTEMS if direction == "can-to-zenoh" else ZENOH_TO_CAN_SYSTEMS:
                if system in lossy or system not in systems:
                    continue
                with tempfile.TemporaryDirectory(prefix="bench-bridge-") as tmp:
                    bench = Bench(args, Path(tmp))
                    try:
                        r = bench.run_one(system, buses, direction)
                    finally:
                        bench.cleanup()
                print(json.dumps(r), flush=True)
                results.append(r)
                if not r["lossless"]:
                    lossy.add(system)
    md = table(results)
    for direction in args.directions.split(","):
        plot(results, out / f"throughput_{direction.replace('-', '_')}.png", direction)
    machine = machine_line()
    (out / "bench.json").write_text(json.dumps({"run_id": run_id, "machine": machine,
                                                "zenoh_runtime": args.zenoh_runtime, "results": results}, indent=2))
    runtime = f" (zenoh-node with ZENOH_RUNTIME={args.zenoh_runtime})" if args.zenoh_runtime else ""
    (out / "bench.md").write_text(f"Bridge benchmark {run_id} on {machine}{runtime}\n\n{md}\n")
    print(md)
    print(f"written: {out}/bench.json, bench.md, throughput_*.png")
    if args.update_readme:
        readme = REPO / "README.md"
        text = readme.read_text()
        begin = "<!-- bench:begin (generated by make bench BENCHMARKS=bridge BENCH_README=1; do not edit) -->"
        end = "<!-- bench:end -->"
        if begin not in text or end not in text:
            sys.exit("README.md has no bench markers")
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1]
        readme.write_text(f"{head}{begin}\nRun {run_id} on {machine}:\n\n{md}\n{end}{tail}")
        print("README.md performance table updated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
