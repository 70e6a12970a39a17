#!/usr/bin/env python3
"""Capture benchmark (make bench-capture): can the bench's two captures record
>= 100 000 frames/s without losing one?

- Zenoh side: zn-flood (firmware/bench/zn-flood, Rust, same zenoh as the
  bridge) publishes samples shaped like the bridge's (16-byte frame, sequence
  attachment) through zenohd on loopback to zn-capture writing its TSV, at
  paced rates (congestion control Drop, as the bridge publishes: the router
  drops what a slow subscriber cannot take, so loss is visible) and once as
  fast as possible with Block (the ceiling). Baseline in the same run: the
  same ceiling with zn-capture writing to /dev/null.
- CAN side: cangen -g 0 on the userspace hub, candump -L into a file (what the
  orchestrator runs); lost = sent - recorded, and the hub's drop counter for
  the reader. Baseline in the same run: cangen with no reader at all (the
  hub's own ceiling).

Every load is bounded (frame count) and on loopback / a private hub. Writes
reports/bench/capture-<run-id>/capture.json and .md; exit 1 if a capture lost
frames at an offered rate >= TARGET_FPS it reached."""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "ucan" / "bench"))
from bench_bus import start_hub  # noqa: E402

from canbench.runkeys import open_session, wait_token  # noqa: E402

TARGET_FPS = 100_000
ZENOH_RATES = (50_000, 100_000, 150_000)
ZENOH_COUNT = 600_000
CAN_COUNT = 500_000
SETTLE_S = 10.0


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_lines(path: Path, expected: int) -> int:
    """Lines in path once it holds `expected`, or once nothing arrived for a second (bounded)."""
    previous, last_change, end = -1, time.monotonic(), time.monotonic() + SETTLE_S
    lines = 0
    while time.monotonic() < end:
        lines = sum(1 for _ in open(path, "rb")) if path.exists() else 0
        if lines >= expected:
            break
        if lines != previous:
            previous, last_change = lines, time.monotonic()
        elif time.monotonic() - last_change > 1.0:
            break
        time.sleep(0.1)  # polling the capture file, bounded by SETTLE_S
    return lines


def stop(proc: subprocess.Popen, close_stdin: bool = False) -> None:
    if close_stdin:
        proc.stdin.close()
    else:
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def zenoh_run(args, workdir: Path, rate: int, block: bool, out: str | None) -> dict:
    """One zn-flood load through a fresh zenohd into a fresh zn-capture."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([args.zenohd, "--no-multicast-scouting", "-l", endpoint],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    session = capture = None
    try:
        session = open_session(endpoint)
        tsv = workdir / f"zenoh-{rate}-{block}.tsv"
        capture = subprocess.Popen([args.zn_capture, "--connect", endpoint, "--key", "bench/flood",
                                    "--ready-token", "bench/capture", "--out", out or str(tsv)],
                                   stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        wait_token(session, "bench/capture", 20)
        flood = subprocess.run([args.zn_flood, "--connect", endpoint, "--key", "bench/flood", "--count",
                                str(ZENOH_COUNT), "--rate", str(rate), *(["--block"] if block else [])],
                               capture_output=True, text=True, timeout=120, check=True)
        seconds = float(re.match(r"\d+ samples in ([\d.]+) s", flood.stdout).group(1))
        if out:  # /dev/null: zn-capture counts what it got when it stops
            stop(capture, close_stdin=True)
            received = int(re.search(rb"zn-capture: (\d+) samples", capture.stderr.read()).group(1))
            gaps = None
        else:
            received = wait_lines(tsv, ZENOH_COUNT)
            stop(capture, close_stdin=True)
            seqs = [int.from_bytes(bytes.fromhex(line.rsplit(b"\t", 1)[1].strip().decode()), "little")
                    for line in open(tsv, "rb")]
            gaps = sum(1 for a, b in zip(seqs, seqs[1:], strict=False) if b != a + 1)
            received = len(seqs)
        return {"side": "zenoh", "capture": "/dev/null" if out else "zn-capture -> file",
                "congestion": "block" if block else "drop", "offered_fps": round(ZENOH_COUNT / seconds),
                "sent": ZENOH_COUNT, "received": received, "lost": ZENOH_COUNT - received, "seq_gaps": gaps}
    finally:
        if capture and capture.poll() is None:
            capture.kill()
        if session:
            session.close()
        stop(router)


def can_run(args, workdir: Path, reader: bool) -> dict:
    """cangen -g 0 on a private hub, candump -L into a file (or no reader: the hub's ceiling)."""
    hub, env = start_hub(Path(args.ucan_build), workdir)  # returns once the hub says it is ready
    dump = None
    try:
        log = workdir / "can.log"
        if reader:
            dump = subprocess.Popen(["candump", "-L", "vcan0"], env=env, stdout=open(log, "wb"))
            deadline = time.monotonic() + 10
            while not any(c["bound"] for c in hub_stats(args, env)["clients"]) and time.monotonic() < deadline:
                time.sleep(0.01)  # candump bound: the hub lists it
        t0 = time.monotonic()
        subprocess.run(["cangen", "vcan0", "-g", "0", "-I", "123", "-L", "8", "-D", "i", "-n", str(CAN_COUNT)],
                       env=env, check=True, timeout=120)
        seconds = time.monotonic() - t0
        recorded = wait_lines(log, CAN_COUNT) if reader else None
        drops = sum(c["rx_drops"] for c in hub_stats(args, env)["clients"])
        return {"side": "can", "capture": "candump -L -> file" if reader else "none (hub ceiling)",
                "offered_fps": round(CAN_COUNT / seconds), "sent": CAN_COUNT, "received": recorded,
                "lost": CAN_COUNT - recorded if reader else None, "hub_drops": drops}
    finally:
        if dump:
            stop(dump)
        stop(hub)


def hub_stats(args, env) -> dict:
    out = subprocess.run([str(Path(args.ucan_build) / "ucanctl"), "stats", "-j"], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout)


def table(results: list[dict]) -> str:
    rows = ["| side | capture | congestion | offered frames/s | sent | recorded | lost |", "|" + "---|" * 7]
    for r in results:
        rows.append(f"| {r['side']} | {r['capture']} | {r.get('congestion', '-')} | {r['offered_fps']} | {r['sent']} "
                    f"| {r['received'] if r['received'] is not None else '-'} "
                    f"| {r['lost'] if r['lost'] is not None else '-'} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ucan-build", default=str(REPO / "build" / "ucan"))
    ap.add_argument("--zn-capture", default=str(REPO / "build" / "firmware" / "zn-capture"))
    ap.add_argument("--zn-flood", required=True)
    ap.add_argument("--zenohd", default=os.environ.get("ZENOHD", "zenohd"))
    args = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-capture-") as tmp:
        work = Path(tmp)
        for rate in ZENOH_RATES:
            results.append(zenoh_run(args, work, rate, block=False, out=None))
            print(json.dumps(results[-1]), flush=True)
        for out in (None, "/dev/null"):
            results.append(zenoh_run(args, work, 0, block=True, out=out))
            print(json.dumps(results[-1]), flush=True)
        for reader in (True, False):
            (work / "can.log").unlink(missing_ok=True)
            results.append(can_run(args, work, reader))
            print(json.dumps(results[-1]), flush=True)
    ceiling = {r["capture"]: r["offered_fps"] for r in results if r.get("congestion") == "block"}
    file_fps, null_fps = ceiling.get("zn-capture -> file", 0), ceiling.get("/dev/null", 0)
    can_file = next(r for r in results if r["side"] == "can" and r["received"] is not None)
    can_bare = next(r for r in results if r["side"] == "can" and r["received"] is None)
    summary = [
        f"Zenoh capture ceiling (Block, all {ZENOH_COUNT} recorded): {file_fps} samples/s into the file, "
        f"{null_fps} into /dev/null (ratio {file_fps / null_fps:.2f})" if null_fps else "",
        f"CAN capture: candump -L recorded {can_file['received']}/{CAN_COUNT} at {can_file['offered_fps']} frames/s; "
        f"the hub alone takes {can_bare['offered_fps']} frames/s "
        f"(ratio {can_file['offered_fps'] / can_bare['offered_fps']:.2f})",
    ]
    failures = [r for r in results if r["offered_fps"] >= TARGET_FPS and r.get("capture") != "/dev/null"
                and r["lost"] not in (0, None)]
    slow = [f"{side} capture offered {fps} < {TARGET_FPS} frames/s" for side, fps in
            (("Zenoh", file_fps), ("CAN", can_file["offered_fps"])) if fps < TARGET_FPS]
    machine = f"{platform.node()}: {os.cpu_count()} cores, {platform.machine()}, Linux {platform.release()}"
    md = "\n".join([table(results), "", *[s for s in summary if s], "", machine])
    run_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    out = REPO / "reports" / "bench" / f"capture-{run_id}"
    out.mkdir(parents=True, exist_ok=True)
    (out / "capture.json").write_text(json.dumps({"results": results, "machine": machine}, indent=2) + "\n")
    (out / "capture.md").write_text(md + "\n")
    print(md)
    for r in failures:
        print(f"bench-capture: FAIL: {r['side']} capture lost {r['lost']} of {r['sent']} "
              f"at {r['offered_fps']} frames/s")
    for s in slow:
        print(f"bench-capture: below target: {s}")
    return 1 if failures or slow else 0


if __name__ == "__main__":
    sys.exit(main())
