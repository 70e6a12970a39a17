"""What every benchmark script shares: the tool options make bench passes to all of them, the
run's output directory, a process's CPU time and RSS from /proc, stopping a process."""
from __future__ import annotations

import argparse
import os
import platform
import signal
import socket
import subprocess
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
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


def add_tool_arguments(ap: argparse.ArgumentParser) -> None:
    """The tools every benchmark script takes (make bench passes one list to all of them)."""
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--bridge", default=str(REPO / "build" / "firmware" / "zenoh-node"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))
    ap.add_argument("--can-load", default=str(REPO / "build" / "bench-tools" / "can-load"))
    ap.add_argument("--zn-flood", default=str(REPO / "build" / "rust" / "release" / "zn-flood"))
    ap.add_argument("--out", help="output directory (default reports/bench/<run-id>)")


def run_id_and_output(args) -> tuple[str, Path]:
    """This run's id (UTC time) and its output directory, created."""
    run_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    out = Path(args.out) if args.out else REPO / "reports" / "bench" / run_id
    out.mkdir(parents=True, exist_ok=True)
    return run_id, out


def machine_line() -> str:
    return f"{platform.node()}: {os.cpu_count()} cores, {platform.machine()}, Linux {platform.release()}"
