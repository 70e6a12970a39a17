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
Python reference, and the floor (bench/tools/floor_bridge.c, up to 8 buses):
the least an immediate bridge does per frame - wake, read, one TCP write -
without Zenoh, so the immediate target's ratio can be held against what no
bridge of that design goes below; one thread polls all its buses. The floor
with a thread per bus (floor-per-bus) reads them as zenoh-node does: where
frames arrive together on several buses, each costs its own wakeup there.

Zenoh -> CAN, the same loads the other way: zn-flood publishes stamped
commands on every bus's tx key (9000 frames/s per bus, all keys interleaved,
one Zenoh session) and one can-load reader counts them on all buses, checking
that each bus's stamps only rise (no reordering, no duplicates). Systems:
zenoh-node and the reference with one frame per command, and both with the
commands a bridge in batching mode publishes (-batch10: one sample per bus
per BATCH_MS holding that period's 90 frames, as when one bridge's batches
drive another bus); each is compared with the reference given the same
commands. Every zenoh-node system also runs on Zenoh's low-latency transport
(-low-latency: --low-latency 1, its zenohd with the transport on).

Per system, direction and load: frames offered, received, lossless or not,
the bridges' CPU time per forwarded frame (every thread's run time from
/proc/<pid>/task/*/schedstat, all instances; the kernel's share from the
tick-counted utime/stime), context switches per frame and peak RSS (the
largest instance). Then one bridge's context switches per frame at 10, 50
and 90 % of one bus (bench.wakeups' runs), in batching mode against the
target of 0.05, and in immediate mode for the record, on both transports.
Ratios zenoh-node / reference are computed within the run; absolute numbers
are only a record of this machine. Where a ratio is judged (the loads both
forward losslessly) every system involved runs JUDGED_RUNS times in all,
round-robin after the sweep, and a load counts with the median of its
lossless runs: a single run swung the immediate ratios by 0.07.

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

from canbench.errors import RunError
from canbench.rig import Rig, Router, bridge_stats, start_bridge, transport_args, zn_capture
from canbench.runkeys import open_session

from . import wakeups
from .common import (
    REPO,
    add_tool_arguments,
    cpu_of_run,
    cpu_split_s,
    ctx_switches,
    machine_line,
    rss_mib,
    run_id_and_output,
    run_ns,
    settle,
)
from .stamps import count_frames, load_rate, zenoh_stamps

BUS_COUNTS = (1, 2, 4, 8, 16, 24, 32, 48, 64)  # can-load: at most 64 interfaces
BUSES_PER_NODE = 8  # ZN_MAX_BUSES
FRAMES_PER_S = 9000  # ~ one saturated 1 Mbit/s bus of 8-byte frames
LOAD_S = 2.0
BATCH_MS = 10
BATCH = f"-batch{BATCH_MS}"
LOW_LATENCY = "-low-latency"  # the bridge and its router on Zenoh's low-latency transport (docs/bridge.md)
REFERENCE = "python-ref"
# bench/tools/floor_bridge.c: the least an immediate CAN -> Zenoh bridge does per frame (wake, read,
# one TCP write), no Zenoh; its CPU is the floor the immediate target is held against
FLOOR = "floor"  # one thread polls all the buses
FLOOR_PER_BUS = "floor-per-bus"  # a thread per bus blocked in its own read, as zenoh-node reads its buses
# each floor and what its row of the table says it is
FLOOR_ROWS = {FLOOR: "wake, read, one TCP write per frame; no Zenoh",
              FLOOR_PER_BUS: "the same, a thread per bus as zenoh-node"}
FLOORS = tuple(FLOOR_ROWS)
FLOOR_MAX_BUSES = 8  # the loads where the reference, and so a judged ratio, is lossless are far below
BRIDGES = ("zenoh-node", f"zenoh-node{BATCH}", f"zenoh-node{LOW_LATENCY}", f"zenoh-node{LOW_LATENCY}{BATCH}")
SYSTEMS = (*BRIDGES, REFERENCE, f"{REFERENCE}{BATCH}", *FLOORS)
FORWARDERS = tuple(s for s in SYSTEMS if s not in FLOORS)  # the floors forward to no one
# CAN -> Zenoh the reference publishes one sample per frame whatever the bridge's mode; Zenoh -> CAN
# "-batch" is the commands' shape, given to both
DIRECTION_SYSTEMS = {"can-to-zenoh": (*BRIDGES, REFERENCE, *FLOORS), "zenoh-to-can": FORWARDERS}
DIRECTIONS = tuple(DIRECTION_SYSTEMS)
SWITCH_TARGET = 0.05  # context switches per frame in batching mode (issue #24)
# runs per load where a ratio is judged (both forward losslessly): a load's CPU and switches per frame are
# the median of its runs, so one run that a neighbour's burst on the 2 cores slowed does not decide
JUDGED_RUNS = 3
SETTLE_S = 10.0
# zenoh-node's per-bus counters that say where a frame went (docs/bridge.md, Keys, token, stats)
CAN_TO_ZENOH_COUNTERS = ("can_rx_frames", "rx_queue_drops", "published_frames", "publish_errors", "unrouted_frames")
ZENOH_TO_CAN_COUNTERS = ("tx_samples", "tx_frames", "tx_queue_full", "can_tx_errors", "tx_abandoned",
                         "tx_refused_closed")


def reference_of(system: str, direction: str) -> str:
    """The reference a system is compared with: Zenoh -> CAN the one given the same commands."""
    return f"{REFERENCE}{BATCH}" if direction == "zenoh-to-can" and system.endswith(BATCH) else REFERENCE


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

    def run_floor(self, system: str, buses: int) -> dict:
        """floor-bridge (system: one of FLOORS) on the buses under the CAN -> Zenoh load (no router: it
        writes to a TCP sink of its own); it reports its own CPU time and switches (getrusage), from
        ready to done."""
        names = [f"vcan{i}" for i in range(buses)]
        self.hub.start(names)
        per_bus = int(FRAMES_PER_S * LOAD_S)
        offered = per_bus * buses
        structure = ["--thread-per-bus"] if system == FLOOR_PER_BUS else []
        floor = self.procs.spawn([str(Path(self.args.can_load).with_name("floor-bridge")), *structure,
                                  ",".join(names), offered, 1000], env=self.env, stdout=subprocess.PIPE, text=True)
        if floor.stdout.readline().strip() != "ready":
            sys.exit(f"{system} (floor-bridge) with {buses} buses did not come up")
        gen = self.procs.spawn([self.args.can_load, "send", ",".join(names), "100", FRAMES_PER_S, per_bus],
                               env=self.env, stdout=subprocess.PIPE, text=True)
        offered_fps = round(offered / json.loads(gen.communicate(timeout=LOAD_S * 10 + SETTLE_S)[0])["seconds"])
        done = json.loads(floor.communicate(timeout=SETTLE_S)[0])  # after every frame, or 1 s after the last
        self.procs.close()
        received = done["frames"]
        return {"direction": "can-to-zenoh", "system": system, "buses": buses, "offered": offered,
                "delivered_fps": offered_fps if received == offered else None, "offered_fps": offered_fps,
                "instances": 1, "received": received, "lossless": received == offered,
                "cpu_us_per_frame": round(done["cpu_ns"] / 1e3 / max(received, 1), 2), "cpu_from_ticks": False,
                "switches_per_frame": round(done["switches"] / max(received, 1), 3), "kernel_share": None,
                "peak_rss_mib": 0.0}

    def run_one(self, system: str, buses: int, direction: str = "can-to-zenoh") -> dict:
        if system in FLOORS:
            return self.run_floor(system, buses)
        names = [f"vcan{i}" for i in range(buses)]
        self.hub.start(names)
        router_args, bridge_args = transport_args(LOW_LATENCY in system)
        router = Router(self.args.zenohd)
        self.procs.add(router.start(*router_args))
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
                period = str(BATCH_MS) if system.endswith(BATCH) else "0"
                cmd = [self.args.bridge, "--router", endpoint, "--can", ",".join(group), "--publish-period-ms",
                       period, "--name", f"zenoh-node-{k}", *bridge_args]
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
        ticks0 = [sum(cpu_split_s(b.pid)[i] for b in bridges) for i in (0, 1)]
        run0 = sum(run_ns(b.pid) for b in bridges)
        switches0 = sum(sum(ctx_switches(b.pid).values()) for b in bridges)
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
            shape = ["--frames-per-sample", FRAMES_PER_S * BATCH_MS // 1000] if system.endswith(BATCH) else []
            gen = self.procs.spawn([self.args.zn_flood, "--connect", endpoint, "--key", ",".join(keys), "--count",
                                    per_bus, "--rate", FRAMES_PER_S, "--stamp-data", "--id", "200", *shape],
                                   stdout=subprocess.PIPE, text=True)
            while gen.poll() is None:
                sample_rss()
                time.sleep(0.05)  # sampling period of the RSS probe
            if gen.returncode != 0:
                sys.exit(f"zn-flood exited {gen.returncode}")
            offered_fps = load_rate(gen.stdout.read(), offered)
            counted = json.loads(reader.communicate(timeout=SETTLE_S + 5)[0])  # stops after 1 s idle
        run_s = (sum(run_ns(b.pid) for b in bridges) - run0) / 1e9
        user_ticks, system_ticks = (sum(cpu_split_s(b.pid)[i] for b in bridges) - ticks0[i] for i in (0, 1))
        cpu, cpu_from_ticks = cpu_of_run(run_s, user_ticks + system_ticks)
        switches = sum(sum(ctx_switches(b.pid).values()) for b in bridges) - switches0
        accounts = self.accounts(session, system, len(bridges), direction)  # after the CPU: its query costs some
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
                "cpu_us_per_frame": round(cpu / max(received, 1) * 1e6, 2), "cpu_from_ticks": cpu_from_ticks,
                "switches_per_frame": round(switches / max(received, 1), 3),
                "kernel_share": round(system_ticks / (user_ticks + system_ticks), 2) if user_ticks + system_ticks
                else None, "peak_rss_mib": round(peak_rss, 1), "accounts": accounts}

    def accounts(self, session, system: str, instances: int, direction: str) -> dict:
        """Where the frames went, once the load is over: the hub's drops for slow readers (the
        bridge's socket CAN -> Zenoh, the counting reader's Zenoh -> CAN) and zenoh-node's own
        counters summed over its instances and buses, so a run with loss says where it lost."""
        try:
            hub = self.hub.stats()
        except (subprocess.CalledProcessError, json.JSONDecodeError):
            hub = {}
        out = {"hub_rx_drops": sum(c.get("rx_drops", 0) for c in hub.get("clients", []))}
        if not system.startswith("zenoh-node"):
            return out
        names = CAN_TO_ZENOH_COUNTERS if direction == "can-to-zenoh" else ZENOH_TO_CAN_COUNTERS
        for k in range(instances):
            stats = bridge_stats(session, "vehicle/can", f"zenoh-node-{k}") or {}
            for bus in stats.get("buses", []):
                for name in names:
                    out[name] = out.get(name, 0) + bus.get(name, 0)
                if direction == "zenoh-to-can":  # per reason in the stats: their sum says enough here
                    out["tx_rejected"] = out.get("tx_rejected", 0) + sum((bus.get("tx_rejected") or {}).values())
        return out

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


LOSS_COUNTERS = ("hub_rx_drops", "rx_queue_drops", "publish_errors", "unrouted_frames", "tx_rejected", "tx_queue_full",
                 "can_tx_errors", "tx_abandoned", "tx_refused_closed")


def lossless_cell(r: dict) -> str:
    """yes, or no with the counters that saw frames go (and what zenoh-node wrote to the bus): where
    the frames went missing."""
    if r["lossless"]:
        return "yes"
    acc = r.get("accounts") or {}
    seen = [f"{name} {acc[name]}" for name in LOSS_COUNTERS if acc.get(name)]
    # Zenoh -> CAN: the commands that reached zenoh-node and the frames it wrote; fewer commands
    # than offered, none refused, is loss before the bridge (the router's congestion drops)
    seen += [f"{name} {acc[name]}" for name in ("tx_samples", "tx_frames") if name in acc]
    return f"no ({', '.join(seen)})" if seen else "no"


def table(results: list[dict]) -> str:
    rows = ["| direction | system | buses | instances | offered frames/s | received | lossless | delivered frames/s | "
            "CPU µs/frame | of it in the kernel | switches/frame | RSS MiB |", "|" + "---|" * 12]
    for r in sorted(results, key=lambda r: (DIRECTIONS.index(r.get("direction", DIRECTIONS[0])),
                                            SYSTEMS.index(r["system"]), r["buses"])):
        rows.append(f"| {r.get('direction', DIRECTIONS[0])} | {r['system']} | {r['buses']} | {r['instances']} | "
                    f"{r['offered_fps']} | {r['received']}/{r['offered']} | {lossless_cell(r)} | "
                    f"{r['delivered_fps']} | {r['cpu_us_per_frame']}{' (ticks)' if r.get('cpu_from_ticks') else ''} | "
                    f"{r['kernel_share']} | {r.get('switches_per_frame', '-')} | {r['peak_rss_mib']} |")
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
                 "| ... relative to the Python reference (given the same commands) | "
                 + " | ".join(f"{best[s] / best[reference_of(s, direction)]:.1f}x"
                              if best.get(reference_of(s, direction)) else "-" for s in systems)
                 + " | >= 3x |"]
        rows.append("| CPU time per frame relative to the reference (median over loads both forward losslessly; "
                    f"a load's CPU: the median of its {JUDGED_RUNS} runs) | "
                    + " | ".join(cpu_ratio(by, s, reference_of(s, direction)) for s in systems)
                    + " | <= 0.1 batching, <= 0.33 immediate |")
        for floor, what in FLOOR_ROWS.items():
            if floor in systems:
                rows.append(f"| ... relative to the {floor} ({what}) | "
                            + " | ".join(cpu_ratio(by, s, floor) for s in systems) + " | |")
        rows.append("| context switches per frame, highest over the loads both forward losslessly (each the median "
                    "of its runs) | "
                    + " | ".join(most_switches(by, s, reference_of(s, direction)) for s in systems)
                    + f" | <= {SWITCH_TARGET} batching |")
        rows.append("| peak RSS MiB (any load) | " + " | ".join(
            str(max([r["peak_rss_mib"] for r in runs if r["system"] == s], default=0)) for s in systems)
            + " | <= 32 |")
    return "\n".join(rows)


def both_lossless(by: dict, system: str, baseline: str) -> list[int]:
    """The bus counts at which system and baseline both forwarded losslessly: where ratios are judged."""
    return [n for (s, n) in by if s == system and (baseline, n) in by
            and by[(s, n)]["lossless"] and by[(baseline, n)]["lossless"]]


def judged(r: dict, key: str) -> float:
    """A run's figure where ratios are judged: the median over its load's lossless runs (judged_runs)."""
    return statistics.median(r.get(f"{key}_runs") or [r[key]])


def cpu_ratio(by: dict, system: str, baseline: str) -> str:
    """Median over the loads both forward losslessly of system's CPU per frame over baseline's, each
    the median of that load's runs."""
    ratios = [judged(by[(system, n)], "cpu_us_per_frame") / judged(by[(baseline, n)], "cpu_us_per_frame")
              for n in both_lossless(by, system, baseline)]
    return f"{statistics.median(ratios):.2f}" if ratios else "-"


def most_switches(by: dict, system: str, baseline: str) -> str:
    """The highest context switches per frame of system over the loads it and baseline both
    forward losslessly (where the CPU ratio is judged too), each the median of that load's runs."""
    loads = both_lossless(by, system, baseline)
    return f"{max(judged(by[(system, n)], 'switches_per_frame') for n in loads):.3f}" if loads else "-"


def run_once(args, system: str, buses: int, direction: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-bridge-") as tmp:
        bench = Bench(args, Path(tmp))
        try:
            return bench.run_one(system, buses, direction)
        finally:
            bench.cleanup()


def judged_runs(args, results: list[dict], direction: str, runs: int) -> None:
    """Runs every system again, round-robin, at the loads where some ratio of its is judged, until
    each such load has runs runs; a load's lossless runs' CPU and switches per frame go into its
    first result (<key>_runs), the runs that lost frames are counted (extra_runs_lossy)."""
    first = {(r["system"], r["buses"]): r for r in results if r["direction"] == direction}
    loads = set()
    for system, _ in first:
        for baseline in {reference_of(system, direction), *FLOORS} - {system}:
            loads |= {(s, n) for n in both_lossless(first, system, baseline) for s in (system, baseline)}
    for key in loads:
        r = first[key]
        r["cpu_us_per_frame_runs"], r["switches_per_frame_runs"], r["extra_runs_lossy"] = (
            [r["cpu_us_per_frame"]], [r["switches_per_frame"]], 0)
    for _ in range(runs - 1):
        for system, buses in sorted(loads, key=lambda k: (k[1], SYSTEMS.index(k[0]))):
            again = run_once(args, system, buses, direction)
            r = first[(system, buses)]
            if not again["lossless"]:
                r["extra_runs_lossy"] += 1
                continue
            r["cpu_us_per_frame_runs"].append(again["cpu_us_per_frame"])
            r["switches_per_frame_runs"].append(again["switches_per_frame"])


SWITCH_RUNS = (("can-to-zenoh", "batching"), ("zenoh-to-can", "batching"), ("can-to-zenoh", "immediate"))


def switch_runs(args, rates: list[int]) -> list[dict]:
    """One bridge at 10, 50 and 90 % of one bus, on either transport: its context switches per frame
    (bench.wakeups)."""
    return [wakeups.measure(args, direction, mode, rate, low_latency) for low_latency in (False, True)
            for direction, mode in SWITCH_RUNS for rate in rates]


def switch_table(results: list[dict]) -> str:
    """Switches per frame against the batching target, next to the floor a period sets: at least one
    wakeup per period while frames flow."""
    rows = [f"| one bridge, one bus | mode | Zenoh transport | frames/s | received | context switches per frame | "
            f"floor: one per {BATCH_MS} ms period | by thread (top 3) | CPU µs/frame | target |", "|" + "---|" * 10]
    for r in results:
        batching = r["mode"] == "batching"
        floor = 1000 / BATCH_MS / r["rate"]
        verdict = ("met" if r["ctx_per_frame"] <= SWITCH_TARGET and r["lossless"] else
                   "not met" + (" (the floor is above it)" if floor > SWITCH_TARGET else ""))
        threads = ", ".join(f"{name} {n}" for name, n in list(r["ctx_per_frame_by_thread"].items())[:3])
        rows.append(f"| {r['direction']} | {r['mode']} | {r.get('transport', 'universal')} | {r['rate']} | "
                    f"{r['received']}/{r['frames']} | {r['ctx_per_frame']} | {f'{floor:.3f}' if batching else '-'} | "
                    f"{threads} | {r['cpu_us_per_frame']} | "
                    f"{f'<= {SWITCH_TARGET}: {verdict}' if batching else 'for the record'} |")
    return "\n".join(rows)


def plot(results: list[dict], path: Path, direction: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = [r for r in results if r.get("direction", DIRECTIONS[0]) == direction]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for s in FORWARDERS:
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
                    f"python-ref, Zenoh -> CAN's of the {BATCH} systems python-ref{BATCH})")
    ap.add_argument("--judged-runs", type=int, default=JUDGED_RUNS,
                    help="runs per load where a ratio is judged (the median counts)")
    ap.add_argument("--zenoh-runtime", default="", help="ZENOH_RUNTIME for zenoh-node only (docs/benchmark.md)")
    ap.add_argument("--switch-rates", default=",".join(map(str, wakeups.RATES)),
                    help="frames/s of one bus for the context-switch runs (empty: none)")
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
            for system in DIRECTION_SYSTEMS[direction]:
                if system in lossy or system not in systems or (system in FLOORS and buses > FLOOR_MAX_BUSES):
                    continue
                r = run_once(args, system, buses, direction)
                print(json.dumps(r), flush=True)
                results.append(r)
                if not r["lossless"]:
                    lossy.add(system)
        judged_runs(args, results, direction, args.judged_runs)
    switches = switch_runs(args, [int(rate) for rate in args.switch_rates.split(",") if rate])
    md = table(results) + (f"\n\n{switch_table(switches)}" if switches else "")
    for direction in args.directions.split(","):
        plot(results, out / f"throughput_{direction.replace('-', '_')}.png", direction)
    machine = machine_line()
    (out / "bench.json").write_text(json.dumps({"run_id": run_id, "machine": machine,
                                                "zenoh_runtime": args.zenoh_runtime, "results": results,
                                                "switches": switches}, indent=2))
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
