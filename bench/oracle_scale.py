"""The oracle at scale: how long the analysis of a run's captures takes and how much memory
it needs, against the frame count. An hour of a saturated 1 Mbit/s bus is 32.4 M frames
(9000 frames/s); the analysis must take minutes with bounded memory (issue 18).

For each size: canbench.groundtruth makes the traffic (one bus, heavy repetition, a fault
every ~1000 frames, batches of up to 16 frames per sample) and writes can.log and zenoh.tsv
as candump and zn-capture do; a fresh process then analyses them as a run does (both
captures read through the bench's codecs, matched, summarised, cycle times per id) and
reports CPU and wall time (wall depends on what else runs) and peak RSS; the counts are
checked against the truth.

  python3 -m bench.oracle_scale --frames 100000 300000 1000000 [--out DIR]

Writes oracle_scale.json (and prints a table) with the per-frame cost and the linear
extrapolation to 32.4 M frames. Files go to a temporary directory, removed at the end."""
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


def write_captures(frames: int, where: Path) -> dict:
    from canbench import groundtruth
    started = time.monotonic()
    truths = groundtruth.generate(seed=frames, frames_per_bus=frames, buses=1, faults=frames // 1000, max_batch=16)
    with open(where / "can.log", "w") as f:
        f.writelines(groundtruth.can_log_lines(truths))
    with open(where / "zenoh.tsv", "w") as f:
        f.writelines(groundtruth.zenoh_lines(truths))
    t = truths[0]
    return {"generate_s": round(time.monotonic() - started, 1), "faults": len(t.faults), "lost": len(t.lost),
            "duplicates": len(t.duplicates), "corrupted": len(t.corrupted), "reordered": len(t.reordered),
            "can_log_mib": round((where / "can.log").stat().st_size / 2**20, 1),
            "zenoh_tsv_mib": round((where / "zenoh.tsv").stat().st_size / 2**20, 1)}


def analyse(where: Path) -> dict:
    """What canbench.analysis does with a run's captures, for one bus, timed."""
    from canbench import oracle
    from canbench.capture import iter_zenoh_capture
    started, cpu0 = time.monotonic(), time.process_time()
    by_key, _ = oracle.zenoh_frames_by_key(iter_zenoh_capture(where / "zenoh.tsv"), {"vehicle/can/rx"})
    received, problems = by_key["vehicle/can/rx"]
    can = oracle.read_candump(where / "can.log", "vcan0")
    read_s = time.monotonic() - started
    c = oracle.compare(can, received)
    summary = c.summary()
    oracle.cycle_times(can)
    oracle.cycle_times(sorted((r for _, r in c.matched), key=lambda o: o.index))
    return {"frames": len(can), "read_s": round(read_s, 1), "wall_s": round(time.monotonic() - started, 1),
            "cpu_s": round(time.process_time() - cpu0, 1),
            "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "lost": summary["lost"], "duplicates": summary["duplicates"], "corrupted": summary["corrupted"],
            "reordered": summary["reordered"], "problems": problems}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[100_000, 300_000, 1_000_000])
    ap.add_argument("--out", type=Path, help="where oracle_scale.json goes (default: print only)")
    ap.add_argument("--analyse", type=Path, help=argparse.SUPPRESS)  # the measured child process
    args = ap.parse_args()
    if args.analyse:
        print(json.dumps(analyse(args.analyse)))
        return 0
    rows = []
    for n in args.frames:
        with tempfile.TemporaryDirectory(prefix="oracle-scale-") as d:
            made = write_captures(n, Path(d))
            child = subprocess.run([sys.executable, "-m", "bench.oracle_scale", "--analyse", d], check=True,
                                   capture_output=True, text=True, timeout=3600)
            got = json.loads(child.stdout)
        agree = all(got[k] == made[k] for k in ("lost", "duplicates", "corrupted", "reordered"))
        rows.append({**made, **got, "agrees_with_truth": agree,
                     "cpu_us_per_frame": round(got["cpu_s"] / n * 1e6, 2),
                     "bytes_per_frame": round(got["peak_rss_mib"] * 2**20 / n)})
        r = rows[-1]
        print(f"{n:>10} frames: analysed in {r['cpu_s']} s CPU ({r['wall_s']} s wall, reading {r['read_s']} s), "
              f"peak RSS "
              f"{r['peak_rss_mib']} MiB, {r['cpu_us_per_frame']} us CPU and {r['bytes_per_frame']} B per frame; truth "
              f"{'agrees' if agree else 'DISAGREES'} ({r['faults']} faults)", flush=True)
    last = rows[-1]
    hour = {"frames": HOUR_FRAMES, "cpu_min": round(last["cpu_us_per_frame"] * HOUR_FRAMES / 1e6 / 60, 1),
            "peak_rss_gib": round(last["bytes_per_frame"] * HOUR_FRAMES / 2**30, 1)}
    print(f"an hour of a saturated 1 Mbit/s bus ({HOUR_FRAMES} frames), extrapolated linearly from "
          f"{last['frames']} frames: {hour['cpu_min']} min of CPU, {hour['peak_rss_gib']} GiB peak RSS")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "oracle_scale.json").write_text(json.dumps({"sizes": rows, "hour_extrapolated": hour}, indent=2))
    return 0 if all(r["agrees_with_truth"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
