#!/usr/bin/env python3
"""Bridge benchmark (make bench-bridge): CAN -> Zenoh forwarding of zenoh-node
next to the Python reference bridge (canbench/refbridge.py: python-can +
eclipse-zenoh, what a user writes first), in the same run, on the same
machine, same bus (the userspace hub), router (zenohd on loopback) and capture
(zn-capture).

Offered load: 1, 2, 4, 8, 16, 24, 32 buses, each at one saturated 1 Mbit/s bus
(9000 frames/s of 8 bytes) for LOAD_S seconds, from one can-load process
(exactly paced, all buses interleaved); per system the loads go up until the
first one with loss. A zenoh-node instance bridges at most ZN_MAX_BUSES = 8
buses, so more buses run several instances (each its own name and keys), as a
vehicle computer with more buses would. Systems: zenoh-node in immediate mode
(one put per frame) and in batching mode (--publish-period-ms BATCH_MS), the
Python reference. Per system and load: frames offered, received on Zenoh,
lossless or not, the bridges' CPU time per forwarded frame (utime + stime from
/proc, all instances) and peak RSS (the largest instance).
Ratios zenoh-node / reference are computed within the run; absolute numbers
are only a record of this machine.

Writes bench.json, bench.md (the table README's performance section is
generated from) and throughput_can_to_zenoh.png. Loopback only; every load is
bounded in frames and time."""
from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
from canbench.runkeys import open_session, wait_token  # noqa: E402

BUS_COUNTS = (1, 2, 4, 8, 16, 24, 32)
BUSES_PER_NODE = 8  # ZN_MAX_BUSES
FRAMES_PER_S = 9000  # ~ one saturated 1 Mbit/s bus of 8-byte frames
LOAD_S = 2.0
BATCH_MS = 10
SYSTEMS = ("zenoh-node", f"zenoh-node-batch{BATCH_MS}", "python-ref")
SETTLE_S = 10.0


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_split_s(pid: int) -> tuple[float, float]:
    """(user, system) CPU seconds of a process, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def cpu_s(pid: int) -> float:
    return sum(cpu_split_s(pid))


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def stop(proc: subprocess.Popen, close_stdin: bool = False) -> None:
    """SIGTERM (or end of stdin for zn-capture), then SIGKILL after 10 s."""
    if close_stdin:
        proc.stdin.close()
    else:
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def count_frames(path: Path) -> int:
    if not path.exists():
        return 0
    return sum(len(line.split("\t")[2]) // 32 for line in open(path) if line.count("\t") == 3)


class Bench:
    def __init__(self, args, workdir: Path):
        self.args, self.workdir = args, workdir
        self.build = Path(args.ucan_build)
        self.env = dict(os.environ, UCAN_DIR=str(workdir), LD_PRELOAD=str(self.build / "libucan-preload.so"))
        self.procs: list[subprocess.Popen] = []

    def spawn(self, cmd, **kw) -> subprocess.Popen:
        p = subprocess.Popen(cmd, **kw)
        self.procs.append(p)
        return p

    def run_one(self, system: str, buses: int) -> dict:
        names = [f"vcan{i}" for i in range(buses)]
        hub = self.spawn([str(self.build / "ucan-hub"), "-d", str(self.workdir), *names],
                         stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while not (self.workdir / "hub.sock").exists() and time.monotonic() < deadline:
            time.sleep(0.01)  # the hub's socket file is its readiness
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        router = self.spawn([self.args.zenohd, "--no-multicast-scouting", "-l", endpoint],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        session = open_session(endpoint)
        capture_file = self.workdir / f"{system}-{buses}.tsv"
        capture = self.spawn([self.args.zn_capture, "--connect", endpoint, "--key", "vehicle/can/**",
                              "--ready-token", "bench/capture", "--out", str(capture_file)], stdin=subprocess.PIPE,
                             stderr=subprocess.DEVNULL)
        wait_token(session, "bench/capture", 20)
        bridges = []
        for k in range(0, buses, BUSES_PER_NODE if system.startswith("zenoh-node") else buses):
            group = names[k:k + (BUSES_PER_NODE if system.startswith("zenoh-node") else buses)]
            if system.startswith("zenoh-node"):
                period = system.removeprefix("zenoh-node").removeprefix("-batch") or "0"
                cmd = [self.args.bridge, "--router", endpoint, "--can", ",".join(group), "--publish-period-ms",
                       period, "--name", f"zenoh-node-{k // BUSES_PER_NODE}"]
            else:
                cmd = [sys.executable, "-m", "canbench.refbridge", "--router", endpoint, "--can", ",".join(group)]
            log = open(self.workdir / f"{system}-{k}.log", "w")
            bridges.append(self.spawn(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO))
        try:
            for group_start in range(0, buses, BUSES_PER_NODE if system.startswith("zenoh-node") else buses):
                wait_token(session, f"vehicle/can/bridges/*/{names[group_start]}/**", 30)
        except TimeoutError:
            sys.exit(f"{system} with {buses} buses did not come up:\n"
                     + "".join(f.read_text()[-1000:] for f in self.workdir.glob(f"{system}-*.log")))
        per_bus = int(FRAMES_PER_S * LOAD_S)
        sys0 = sum(cpu_split_s(b.pid)[1] for b in bridges)
        cpu0 = sum(cpu_s(b.pid) for b in bridges)
        gen = subprocess.Popen([self.args.can_load, "send", ",".join(names), "100", str(FRAMES_PER_S),
                                str(per_bus)], env=self.env, stdout=subprocess.PIPE, text=True)
        peak_rss = 0.0
        while gen.poll() is None:
            peak_rss = max([peak_rss] + [rss_mib(b.pid) for b in bridges])
            time.sleep(0.05)  # sampling period of the RSS probe
        sent = json.loads(gen.stdout.read())
        offered = per_bus * buses
        # wait until every frame arrived, or nothing more arrives for a second (bounded)
        received, last_change, previous = 0, time.monotonic(), -1
        end = time.monotonic() + SETTLE_S
        while time.monotonic() < end:
            received = count_frames(capture_file)
            if received >= offered:
                break
            if received != previous:
                previous, last_change = received, time.monotonic()
            elif time.monotonic() - last_change > 1.0:
                break
            peak_rss = max([peak_rss] + [rss_mib(b.pid) for b in bridges])
            time.sleep(0.1)  # polling the capture file, bounded
        cpu = sum(cpu_s(b.pid) for b in bridges) - cpu0
        system_cpu = sum(cpu_split_s(b.pid)[1] for b in bridges) - sys0
        for p in (*bridges, capture, router, hub):
            stop(p, close_stdin=p is capture)
        session.close()
        received = count_frames(capture_file)
        # sustained rate: first send (can-load stamps its frames) to last receive, so a backlog worked off
        # after the load counts at the rate it was really carried
        from bench_paths import zenoh_stamps  # bench_paths imports this module: import when used
        stamps = zenoh_stamps(capture_file)
        span_s = (max(r for _, r in stamps) - min(t for t, _ in stamps)) / 1e9 if stamps else 0
        return {"system": system, "buses": buses, "offered": offered,
                "delivered_fps": round(len(stamps) / span_s) if span_s > 0 else None,
                "offered_fps": round(offered / sent["seconds"]), "instances": len(bridges),
                "received": received, "lossless": received == offered,
                "cpu_us_per_frame": round(cpu / max(received, 1) * 1e6, 2),
                "kernel_share": round(system_cpu / cpu, 2) if cpu else None, "peak_rss_mib": round(peak_rss, 1)}

    def cleanup(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()


def table(results: list[dict]) -> str:
    rows = ["| system | buses | instances | offered frames/s | received | lossless | delivered frames/s | "
            "CPU µs/frame | of it in the kernel | RSS MiB |", "|" + "---|" * 10]
    for r in sorted(results, key=lambda r: (SYSTEMS.index(r["system"]), r["buses"])):
        rows.append(f"| {r['system']} | {r['buses']} | {r['instances']} | {r['offered_fps']} | "
                    f"{r['received']}/{r['offered']} | {'yes' if r['lossless'] else 'no'} | {r['delivered_fps']} | "
                    f"{r['cpu_us_per_frame']} | {r['kernel_share']} | {r['peak_rss_mib']} |")
    # a load counts as carried only as far as it was sustained (not a backlog worked off afterwards)
    best = {s: max([min(r["offered_fps"], r["delivered_fps"] or 0) for r in results
                    if r["system"] == s and r["lossless"]], default=0) for s in SYSTEMS}
    by = {(r["system"], r["buses"]): r for r in results}
    ref = "python-ref"
    rows += ["", "| | " + " | ".join(SYSTEMS) + " | target |", "|---|" + "---|" * (len(SYSTEMS) + 1),
             "| highest lossless CAN -> Zenoh frames/s | " + " | ".join(str(best[s]) for s in SYSTEMS)
             + " | >= 144000 |",
             "| ... relative to the Python reference | "
             + " | ".join(f"{best[s] / best[ref]:.1f}x" if best[ref] else "-" for s in SYSTEMS) + " | >= 3x |"]
    ratios = []
    for s in SYSTEMS:
        common = [(by[(s, n)]["cpu_us_per_frame"], by[(ref, n)]["cpu_us_per_frame"]) for (sys_, n) in by
                  if sys_ == s and (ref, n) in by and by[(s, n)]["lossless"] and by[(ref, n)]["lossless"]]
        ratios.append(f"{statistics.median(a / b for a, b in common):.2f}" if common else "-")
    rows.append("| CPU time per frame relative to the reference (median over loads both forward losslessly) | "
                + " | ".join(ratios) + " | <= 0.1 |")
    rows.append("| peak RSS MiB (any load) | " + " | ".join(
        str(max([r["peak_rss_mib"] for r in results if r["system"] == s], default=0)) for s in SYSTEMS)
        + " | <= 32 |")
    return "\n".join(rows)


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for s in SYSTEMS:
        pts = sorted((r for r in results if r["system"] == s), key=lambda r: r["buses"])
        ax.plot([r["offered_fps"] for r in pts], [r["delivered_fps"] or 0 for r in pts], marker="o", label=s)
    top = max((r["offered_fps"] for r in results), default=1)
    ax.plot([0, top], [0, top], color="grey", linestyle=":", label="offered")
    ax.set_xlabel("offered CAN frames/s (9000 per bus)")
    ax.set_ylabel("frames/s delivered on Zenoh (first send to last receive)")
    ax.set_title("CAN -> Zenoh throughput")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--bridge", default=str(REPO / "build" / "firmware" / "zenoh-node"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))
    ap.add_argument("--can-load", default=str(REPO / "build" / "ucan" / "can-load"))
    ap.add_argument("--zn-flood", help="unused here (make bench passes one tool list to every benchmark)")
    ap.add_argument("--buses", default=",".join(map(str, BUS_COUNTS)))
    ap.add_argument("--out", help="output directory (default reports/bench/<run-id>)")
    ap.add_argument("--update-readme", action="store_true",
                    help="replace README's performance table (between the bench markers) with this run's")
    args = ap.parse_args()
    run_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    out = Path(args.out) if args.out else REPO / "reports" / "bench" / run_id
    out.mkdir(parents=True, exist_ok=True)
    results = []
    lossy: set[str] = set()  # systems past their first load with loss: no higher load for them
    for buses in [int(b) for b in args.buses.split(",")]:
        for system in SYSTEMS:
            if system in lossy:
                continue
            with tempfile.TemporaryDirectory(prefix="bench-bridge-") as tmp:
                bench = Bench(args, Path(tmp))
                try:
                    r = bench.run_one(system, buses)
                finally:
                    bench.cleanup()
            print(json.dumps(r), flush=True)
            results.append(r)
            if not r["lossless"]:
                lossy.add(system)
    md = table(results)
    plot(results, out / "throughput_can_to_zenoh.png")
    machine = f"{platform.node()}: {os.cpu_count()} cores, {platform.machine()}, Linux {platform.release()}"
    (out / "bench.json").write_text(json.dumps({"run_id": run_id, "machine": machine, "results": results},
                                               indent=2))
    (out / "bench.md").write_text(f"Bridge benchmark {run_id} on {machine}\n\n{md}\n")
    print(md)
    print(f"written: {out}/bench.json, bench.md, throughput_can_to_zenoh.png")
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
