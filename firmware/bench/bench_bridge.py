#!/usr/bin/env python3
"""Bridge benchmark (make bench-bridge): CAN -> Zenoh forwarding of zenoh-node
next to the Python reference bridge (canbench/refbridge.py: python-can +
eclipse-zenoh, what a user writes first), in the same run, on the same
machine, same bus (the userspace hub), router (zenohd on loopback) and capture
(zn-capture).

Offered load: 1, 2, 4, 8 buses (ZN_MAX_BUSES), each fed by cangen at about one saturated
1 Mbit/s bus (9 frames per ms, 8-byte frames) for LOAD_S seconds. Per system
and load: frames offered, received on Zenoh, lossless or not, the bridge's
CPU time per forwarded frame (utime + stime from /proc) and its peak RSS.
Ratios zenoh-node / reference are computed within the run; absolute numbers
are only a record of this machine.

Writes reports/bench/<run-id>/bench.json and bench.md (the table README's
performance section is generated from). Loopback only; every load is bounded
in frames and time."""
from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
from canbench.runkeys import open_session, wait_token  # noqa: E402

BUS_COUNTS = (1, 2, 4, 8)  # zenoh-node bridges at most ZN_MAX_BUSES = 8 buses per instance
FRAMES_PER_MS = 9  # ~ one saturated 1 Mbit/s bus of 8-byte frames
LOAD_S = 2.0
SETTLE_S = 10.0


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


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
        if system == "zenoh-node":
            cmd = [self.args.bridge, "--router", endpoint, "--can", ",".join(names), "--publish-period-ms", "0"]
        else:
            cmd = [sys.executable, "-m", "canbench.refbridge", "--router", endpoint, "--can", ",".join(names)]
        log = open(self.workdir / f"{system}.log", "w")
        bridge = self.spawn(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        try:
            wait_token(session, "vehicle/can/bridges/**", 30)
        except TimeoutError:
            sys.exit(f"{system} with {buses} buses did not come up:\n"
                     + (self.workdir / f"{system}.log").read_text()[-2000:])
        per_bus = int(FRAMES_PER_MS * 1000 * LOAD_S)
        cpu0 = cpu_s(bridge.pid)
        t0 = time.monotonic()
        gens = [subprocess.Popen(["cangen", n, "-I", f"{0x100 + i:X}", "-L", "8", "-D", "i", "-g", "1",
                                  "-c", str(FRAMES_PER_MS), "-n", str(per_bus)], env=self.env)
                for i, n in enumerate(names)]
        peak_rss = 0.0
        while any(g.poll() is None for g in gens):
            peak_rss = max(peak_rss, rss_mib(bridge.pid))
            time.sleep(0.05)  # sampling period of the RSS probe
        offered_s = time.monotonic() - t0
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
            peak_rss = max(peak_rss, rss_mib(bridge.pid))
            time.sleep(0.1)  # polling the capture file, bounded
        cpu = cpu_s(bridge.pid) - cpu0
        for p in (bridge, capture, router, hub):
            stop(p, close_stdin=p is capture)
        session.close()
        received = count_frames(capture_file)
        return {"system": system, "buses": buses, "offered": offered, "offered_fps": round(offered / offered_s),
                "received": received, "lossless": received == offered,
                "cpu_us_per_frame": round(cpu / max(received, 1) * 1e6, 2), "peak_rss_mib": round(peak_rss, 1)}

    def cleanup(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()


def table(results: list[dict]) -> str:
    rows = ["| buses | offered frames/s | zenoh-node received | lossless | CPU µs/frame | RSS MiB | "
            "Python ref. received | lossless | CPU µs/frame | RSS MiB | CPU ratio |", "|" + "---|" * 11]
    by = {(r["system"], r["buses"]): r for r in results}
    for n in sorted({r["buses"] for r in results}):
        z, p = by.get(("zenoh-node", n)), by.get(("python-ref", n))
        if not z or not p:
            continue
        ratio = z["cpu_us_per_frame"] / p["cpu_us_per_frame"] if p["cpu_us_per_frame"] else 0
        rows.append(f"| {n} | {z['offered_fps']} | {z['received']}/{z['offered']} | {'yes' if z['lossless'] else 'no'} "
                    f"| {z['cpu_us_per_frame']} | {z['peak_rss_mib']} | {p['received']}/{p['offered']} | "
                    f"{'yes' if p['lossless'] else 'no'} | {p['cpu_us_per_frame']} | {p['peak_rss_mib']} | "
                    f"{ratio:.2f} |")
    best = {s: max([r["offered_fps"] for r in results if r["system"] == s and r["lossless"]], default=0)
            for s in ("zenoh-node", "python-ref")}
    rows.append("")
    rows.append(f"Highest lossless CAN -> Zenoh rate: zenoh-node {best['zenoh-node']} frames/s, Python reference "
                f"{best['python-ref']} frames/s" + (f" ({best['zenoh-node'] / best['python-ref']:.1f}x)"
                                                     if best["python-ref"] else ""))
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--bridge", default=str(REPO / "build" / "firmware" / "zenoh-node"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))
    ap.add_argument("--buses", default=",".join(map(str, BUS_COUNTS)))
    ap.add_argument("--update-readme", action="store_true",
                    help="replace README's performance table (between the bench markers) with this run's")
    args = ap.parse_args()
    run_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    out = REPO / "reports" / "bench" / run_id
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for buses in [int(b) for b in args.buses.split(",")]:
        for system in ("zenoh-node", "python-ref"):
            with tempfile.TemporaryDirectory(prefix="bench-bridge-") as tmp:
                bench = Bench(args, Path(tmp))
                try:
                    r = bench.run_one(system, buses)
                finally:
                    bench.cleanup()
            print(json.dumps(r), flush=True)
            results.append(r)
    md = table(results)
    machine = f"{platform.node()}: {os.cpu_count()} cores, {platform.machine()}, Linux {platform.release()}"
    (out / "bench.json").write_text(json.dumps({"run_id": run_id, "machine": machine, "results": results},
                                               indent=2))
    (out / "bench.md").write_text(f"Bridge benchmark {run_id} on {machine}\n\n{md}\n")
    print(md)
    print(f"written: {out}/bench.json, bench.md")
    if args.update_readme:
        readme = REPO / "README.md"
        text = readme.read_text()
        begin, end = "<!-- bench:begin (generated by make bench-bridge; do not edit) -->", "<!-- bench:end -->"
        if begin not in text or end not in text:
            sys.exit("README.md has no bench markers")
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1]
        readme.write_text(f"{head}{begin}\nRun {run_id} on {machine}:\n\n{md}\n{end}{tail}")
        print("README.md performance table updated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
