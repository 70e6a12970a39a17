"""The oracle at scale: how long the analysis of a run's captures takes and how much memory
it needs, against the frame count. An hour of a saturated 1 Mbit/s bus is 32.4 M frames
(9000 frames/s); the analysis must take minutes with bounded memory (issue 18).

For each size: canbench.groundtruth makes the traffic (one bus, heavy repetition, a fault
every ~1000 frames, batches of up to 16 frames per sample) in chunks of CHUNK_FRAMES, each
stamped more than the oracle's window after the one before (so the generator's memory stays
bounded too and its truth per chunk is the truth of the whole), and writes can.log and
zenoh.tsv as candump and zn-capture do; a fresh process then analyses them as a run does and
reports CPU and wall time (wall depends on what else runs) and peak RSS; the counts are
checked against the truth. Modes of the analysis:

  stream  compare_stream: both captures read as they go in one time-ordered pass, cycle times
          per id on both sides, bounded memory (the default)
  whole   every frame read into lists, compare() and cycle_times(), as canbench.analysis does

  python3 -m bench.oracle_scale --frames 1000000 3000000 [--mode stream] [--out DIR] [--keep DIR]
  python3 -m bench.oracle_scale --saturated 80    # the window's memory at 9000 frames/s, 80 s

Writes oracle_scale.json (and prints a table) with the per-frame cost. Files go to a temporary
directory, removed at the end (--keep DIR: written there and kept, e.g. to analyse them again
with another version of the oracle: `python3 -m bench.oracle_scale --analyse DIR`)."""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HOUR_FRAMES = 9000 * 3600  # a saturated 1 Mbit/s bus of 8-byte frames for an hour
CHUNK_FRAMES = 250_000     # frames generated at a time
TRUTH = ("lost", "duplicates", "corrupted", "reordered")


def write_captures(frames: int, where: Path) -> dict:
    from canbench import groundtruth
    from canbench.oracle import MATCH_WINDOW_NS
    started = time.monotonic()
    totals = dict.fromkeys(("faults", *TRUTH), 0)
    t0 = groundtruth.T0_NS
    seq = 0
    with open(where / "can.log", "w") as can, open(where / "zenoh.tsv", "w") as zen:
        for chunk, at in enumerate(range(0, frames, CHUNK_FRAMES)):
            n = min(CHUNK_FRAMES, frames - at)
            truths = groundtruth.generate(seed=frames + chunk, frames_per_bus=n, buses=1, faults=n // 1000,
                                          max_batch=16, t0_ns=t0)
            can.writelines(groundtruth.can_log_lines(truths))
            zen.writelines(groundtruth.zenoh_lines(truths, first_seq=seq))
            t = truths[0]
            for k, v in (("faults", t.faults), ("lost", t.lost), ("duplicates", t.duplicates),
                         ("corrupted", t.corrupted), ("reordered", t.reordered)):
                totals[k] += len(v)
            seq += len(t.delivered)
            t0 = t.sent[-1][0] + MATCH_WINDOW_NS + 1_000_000_000
    return {"generate_s": round(time.monotonic() - started, 1), **totals,
            "can_log_mib": round((where / "can.log").stat().st_size / 2**20, 1),
            "zenoh_tsv_mib": round((where / "zenoh.tsv").stat().st_size / 2**20, 1)}


def peak_rss_mib() -> float:
    """This process's peak resident set (VmHWM: its own memory since exec; getrusage's ru_maxrss
    would also count the parent's that a vfork + exec child starts from)."""
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return round(int(line.split()[1]) / 1024, 1)
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def analyse(where: Path, mode: str) -> dict:
    """What canbench.analysis does with a run's captures, for one bus, timed."""
    from canbench import oracle
    from canbench.capture import iter_zenoh_capture
    started, cpu0 = time.monotonic(), time.process_time()
    problems: list[str] = []
    if mode == "stream":
        can_cycles, zenoh_cycles = oracle.CycleTimes(), oracle.CycleTimes()

        def sent():
            for o in oracle.iter_candump_frames(where / "can.log", "vcan0"):
                can_cycles.add(o)
                yield o
        received = oracle.iter_zenoh_frames(iter_zenoh_capture(where / "zenoh.tsv"), "vehicle/can/rx", problems)
        c = oracle.compare_stream(sent(), received, on_match=lambda s, r: zenoh_cycles.add(r))
        summary = c.summary()
        can_cycles.result()
        zenoh_cycles.result()
    else:
        by_key, _ = oracle.zenoh_frames_by_key(iter_zenoh_capture(where / "zenoh.tsv"), {"vehicle/can/rx"})
        received_list, problems = by_key["vehicle/can/rx"]
        can = oracle.read_candump(where / "can.log", "vcan0")
        c = oracle.compare(can, received_list)
        summary = c.summary()
        oracle.cycle_times(can)
        oracle.cycle_times(sorted((r for _, r in c.matched), key=lambda o: o.index))
    return {"mode": mode, "frames": summary["sent"], "wall_s": round(time.monotonic() - started, 1),
            "cpu_s": round(time.process_time() - cpu0, 1),
            "peak_rss_mib": peak_rss_mib(),
            **{k: summary[k] for k in TRUTH}, "latency": summary["latency"], "problems": problems}


def saturated(seconds: int) -> dict:
    """compare_stream's memory at a saturated bus: 9000 frames/s for `seconds` (a counter frame
    every fourth, 20 constant ones between), each delivered 0.3 ms later; no files, so what is
    measured is the window itself (peak RSS above the interpreter and its imports)."""
    from canbench import wire
    from canbench.oracle import Observed, compare_stream
    base = peak_rss_mib()
    n, gap = 9000 * seconds, 1_000_000_000 // 9000
    constant = [wire.Frame(0x100 + k, 8, bytes([k]) + bytes(7)) for k in range(20)]

    def sent():
        for i in range(n):
            f = wire.Frame(0x200, 8, i.to_bytes(8, "little")) if i % 4 == 0 else constant[i % 20]
            yield Observed(f, 1_700_000_000_000_000_000 + i * gap, i, line=i + 1)

    def received():
        for o in sent():
            yield Observed(o.frame, o.t_ns + 300_000, o.index, key="k")
    cpu0 = time.process_time()
    s = compare_stream(sent(), received()).summary()
    return {"seconds": seconds, "frames": n, "matched": s["matched"], "lost": s["lost"],
            "cpu_s": round(time.process_time() - cpu0, 1),
            "peak_rss_above_imports_mib": round(peak_rss_mib() - base, 1)}


def measure(n: int, where: Path, mode: str) -> dict:
    made = write_captures(n, where)
    child = subprocess.run([sys.executable, "-m", "bench.oracle_scale", "--analyse", str(where), "--mode", mode],
                           check=True, capture_output=True, text=True, timeout=3600)
    got = json.loads(child.stdout)
    agree = all(got[k] == made[k] for k in TRUTH)
    return {**made, **got, "agrees_with_truth": agree, "cpu_us_per_frame": round(got["cpu_s"] / n * 1e6, 2),
            "bytes_per_frame": round(got["peak_rss_mib"] * 2**20 / n)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[1_000_000, 3_000_000])
    ap.add_argument("--mode", choices=("stream", "whole"), default="stream")
    ap.add_argument("--out", type=Path, help="where oracle_scale.json goes (default: print only)")
    ap.add_argument("--keep", type=Path, help="write the captures under DIR/<frames> and keep them")
    ap.add_argument("--analyse", type=Path, help="analyse the captures in this directory (one JSON line)")
    ap.add_argument("--saturated", type=int, metavar="SECONDS",
                    help="only the window's memory at a saturated bus (9000 frames/s) for SECONDS (one JSON line)")
    args = ap.parse_args()
    if args.saturated:
        print(json.dumps(saturated(args.saturated)))
        return 0
    if args.analyse:
        print(json.dumps(analyse(args.analyse, args.mode)))
        return 0
    rows = []
    for n in args.frames:
        if args.keep:
            where = args.keep / str(n)
            where.mkdir(parents=True, exist_ok=True)
            rows.append(measure(n, where, args.mode))
        else:
            with tempfile.TemporaryDirectory(prefix="oracle-scale-") as d:
                rows.append(measure(n, Path(d), args.mode))
        r = rows[-1]
        print(f"{n:>10} frames ({r['mode']}): analysed in {r['cpu_s']} s CPU ({r['wall_s']} s wall), peak RSS "
              f"{r['peak_rss_mib']} MiB, {r['cpu_us_per_frame']} us CPU and {r['bytes_per_frame']} B per frame; "
              f"truth {'agrees' if r['agrees_with_truth'] else 'DISAGREES'} ({r['faults']} faults)", flush=True)
    last = rows[-1]
    hour = {"frames": HOUR_FRAMES, "cpu_min": round(last["cpu_us_per_frame"] * HOUR_FRAMES / 1e6 / 60, 1)}
    print(f"an hour of a saturated 1 Mbit/s bus ({HOUR_FRAMES} frames) at {last['cpu_us_per_frame']} us per frame: "
          f"{hour['cpu_min']} min of CPU; peak RSS at {last['frames']} frames: {last['peak_rss_mib']} MiB")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "oracle_scale.json").write_text(json.dumps({"sizes": rows, "hour": hour}, indent=2))
    return 0 if all(r["agrees_with_truth"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
