"""What every benchmark script shares: the tool options make bench passes to all of them, the
run's output directory, a process's CPU time and RSS from /proc. Starting and stopping the
processes is the rig's (canbench/rig.py), which the tests use too."""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def cpu_split_s(pid: int) -> tuple[float, float]:
    """(user, system) CPU seconds of a process, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def cpu_s(pid: int) -> float:
    return sum(cpu_split_s(pid))


def ctx_switches(pid: int) -> dict[str, int]:
    """Voluntary + involuntary context switches so far of every thread of a process, by thread
    name (Zenoh's runtimes name theirs, e.g. tx-0, rx-1, app-0; the bridge's are the process's)."""
    by_name: dict[str, int] = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            name = (task / "comm").read_text().strip()
            switches = sum(int(line.split()[1]) for line in (task / "status").read_text().splitlines()
                           if line.startswith(("voluntary_ctxt_switches:", "nonvoluntary_ctxt_switches:")))
        except OSError:  # a thread that just ended
            continue
        by_name[name] = by_name.get(name, 0) + switches
    return by_name


def run_ns(pid: int) -> int:
    """CPU time of every thread of a process so far, ns (schedstat: not tick-rounded)."""
    total = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        try:
            total += int(stat.read_text().split()[0])
        except OSError:  # a thread that just ended
            pass
    return total


def cpu_of_run(run_s: float, ticks_s: float) -> tuple[float, bool]:
    """A run's CPU seconds from its schedstat delta (run_ns: the threads alive when it is read),
    unless the process's tick total (/proc/<pid>/stat, which keeps the time of threads that
    ended) says a thread ended in the run with more than the ticks' rounding (10 ms per
    reading, 5 %): then the ticks, flagged. Returns (seconds, from_ticks)."""
    if ticks_s > run_s * 1.05 + 0.02:
        return ticks_s, True
    return run_s, False


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def add_rig_arguments(ap: argparse.ArgumentParser) -> None:
    """The rig's programs: the userspace bus's build, the bridge, zn-capture, zenohd."""
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--bridge", default=str(REPO / "build" / "firmware" / "zenoh-node"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))


def add_tool_arguments(ap: argparse.ArgumentParser) -> None:
    """The tools every benchmark script takes (make bench passes one list to all of them)."""
    add_rig_arguments(ap)
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


def settle(count, expected: int, settle_s: float, step_s: float, tick=None) -> int:
    """count() until it reaches expected, or nothing more arrived for a second, or settle_s passed
    (a capture file still being written); tick() runs at each poll (e.g. an RSS probe)."""
    n, previous, last_change = 0, -1, time.monotonic()
    end = time.monotonic() + settle_s
    while time.monotonic() < end:
        n = count()
        if n >= expected:
            break
        if n != previous:
            previous, last_change = n, time.monotonic()
        elif time.monotonic() - last_change > 1.0:
            break
        if tick:
            tick()
        time.sleep(step_s)  # polling a capture file, bounded by settle_s
    return n
