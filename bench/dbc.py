"""DBC load and signal-decode time at scale (make bench BENCHMARKS=dbc): cantools loading real
and generated databases, and the signal evaluator (canbench.signals) judging every signal of
every message over a stream of frames, with its memory bounded.

Databases:
  vehicle   tests/data/dbc/cantools/vehicle.dbc: 217 messages, 29-bit ids, 462 signals (from
            cantools' sources, MIT)
  abs       tests/data/dbc/cantools/abs.dbc: 18 messages, one multiplexed, value tables
  generated --messages messages (default 1000) made with cantools' API and dumped as DBC text:
            half 29-bit, a quarter multiplexed (4 pages), scaled, offset, signed and float
            signals, value tables, GenMsgCycleTime

Per database: load time (cantools parse), and for --frames frames (default 200 000; each message
in turn, values encoded by cantools) the evaluator's frames/s with a range gate on every signal,
its peak traced memory (tracemalloc, in a second pass) and the violations it found (must be 0: every value is in
its range). Results: <out>/dbc.json and a table on stdout. Exit 1 when a bound is missed
(--max-load-s, --min-frames-per-s), so a slow cantools or evaluator shows in the nightly run.

  python3 -m bench.dbc [--frames 200000] [--messages 1000] [--out DIR]"""
from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import cantools
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from canbench import signals, wire

from .common import REPO, machine_line, run_id_and_output

SHIPPED = {"vehicle": REPO / "tests" / "data" / "dbc" / "cantools" / "vehicle.dbc",
           "abs": REPO / "tests" / "data" / "dbc" / "cantools" / "abs.dbc"}


def generated_dbc(count: int, seed: int = 1) -> str:
    """A large DBC made with cantools' API: every shape the evaluator must decode."""
    rng = random.Random(seed)
    messages = []
    for n in range(count):
        extended = n % 2 == 1
        frame_id = (0x18000000 + n) if extended else (0x100 + n % 0x6FF)
        if not extended and any(m.frame_id == frame_id and not m.is_extended_frame for m in messages):
            frame_id, extended = 0x10000000 + n, True
        if n % 4 == 0:  # multiplexed: 4 pages of two 16-bit signals each
            sigs = [Signal("Page", 0, 8, is_multiplexer=True)]
            for page in range(4):
                for k in range(2):
                    sigs.append(Signal(f"P{page}S{k}", 8 + 16 * k, 16, multiplexer_ids=[page],
                                       multiplexer_signal="Page", is_signed=k == 1,
                                       conversion=BaseConversion.factory(scale=0.1, offset=-50 * k)))
        else:
            sigs = [Signal("Counter", 0, 4), Signal("Scaled", 8, 16, conversion=BaseConversion.factory(
                        scale=0.25, offset=-1000)),
                    Signal("Signed", 24, 8, is_signed=True),
                    Signal("Mode", 4, 4, conversion=BaseConversion.factory(
                        scale=1, offset=0, choices={0: "Off", 1: "On", 2: "Fault"})),
                    Signal("Float", 32, 32, conversion=BaseConversion.factory(scale=1, offset=0, is_float=True))]
        messages.append(Message(frame_id, f"Msg{n}", 8, sigs, is_extended_frame=extended,
                                cycle_time=rng.choice([10, 20, 50, 100, 1000])))
    return Database(messages=messages).as_dbc_string()


def frames_of(db, count: int, seed: int = 2) -> list[wire.Frame]:
    """count frames, each message of the DBC in turn, its values encoded by cantools (every
    multiplexer page in turn)."""
    rng = random.Random(seed)
    templates = []
    for m in db.messages:
        if m.length > 8:
            continue  # classic CAN only: the bridge's frames carry at most 8 bytes
        pages = [None]
        mux = next((s for s in m.signals if s.is_multiplexer), None)
        if mux is not None:
            pages = sorted({i for s in m.signals for i in (s.multiplexer_ids or [])})
        for page in pages:
            values = {}
            for s in m.signals:
                if s.multiplexer_ids is not None and page not in s.multiplexer_ids:
                    continue
                if s.is_multiplexer:
                    values[s.name] = page
                elif s.choices:
                    values[s.name] = rng.choice(list(s.choices.values()))
                else:
                    low = s.minimum if s.minimum is not None else s.conversion.raw_to_scaled(0, False)
                    values[s.name] = low
            try:
                data = m.encode(values, strict=False)
            except Exception:  # noqa: BLE001 - a message this DBC cannot encode with defaults: skipped
                continue
            templates.append(wire.Frame(m.frame_id, len(data), bytes(data), m.is_extended_frame))
    return [templates[i % len(templates)] for i in range(count)]


def every_signal(db, bus: str = "vcan0") -> tuple[signals.Gate, ...]:
    """A range gate on every signal: wide enough that every encoded value is within it."""
    return tuple(signals.Gate(f"{m.name}.{s.name}", m.name, s.name, (bus,), s.unit or "", range=(-1e40, 1e40))
                 for m in db.messages for s in m.signals)


def measure(name: str, path: Path, frame_count: int) -> dict:
    t = time.perf_counter()
    db = cantools.database.load_file(str(path), strict=False)
    load_s = time.perf_counter() - t
    frames = frames_of(db, frame_count)
    gates = every_signal(db)

    def judge() -> list[signals.Series]:
        evaluator = signals.Evaluator(gates, db, "can", "vcan0", 0)
        for i, f in enumerate(frames):
            evaluator.feed(f, i * 100_000, "bench")
        return evaluator.finish()
    t = time.perf_counter()
    series = judge()
    decode_s = time.perf_counter() - t
    tracemalloc.start()  # a second pass for the evaluator's memory (tracemalloc slows it several times)
    judge()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"dbc": name, "messages": len(db.messages), "signals": sum(len(m.signals) for m in db.messages),
            "extended": sum(m.is_extended_frame for m in db.messages),
            "multiplexed": sum(m.is_multiplexed() for m in db.messages), "load_s": round(load_s, 3),
            "frames": len(frames), "decode_s": round(decode_s, 3),
            "frames_per_s": round(len(frames) / decode_s) if decode_s else None,
            "values": sum(s.count for s in series), "violations": sum(s.violation_count for s in series),
            "evaluator_peak_mib": round(peak / 2**20, 2),
            "max_points": max((len(s.times) for s in series), default=0)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--messages", type=int, default=1000, help="of the generated DBC")
    ap.add_argument("--max-load-s", type=float, default=30.0, help="bound on each database's load time")
    ap.add_argument("--min-frames-per-s", type=float, default=5000.0, help="bound on the evaluator's rate")
    ap.add_argument("--out", help="output directory (default reports/bench/<run-id>)")
    args = ap.parse_args(argv)
    _, out = run_id_and_output(args)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        generated = Path(tmp) / "generated.dbc"
        generated.write_text(generated_dbc(args.messages))
        for name, path in [*SHIPPED.items(), ("generated", generated)]:
            results.append(measure(name, path, args.frames))
    print(machine_line())
    print(f"{'dbc':<10} {'messages':>8} {'signals':>8} {'29-bit':>7} {'mux':>5} {'load s':>7} {'frames':>8} "
          f"{'frames/s':>9} {'values':>9} {'peak MiB':>8} {'violations':>10}")
    failed = []
    for r in results:
        print(f"{r['dbc']:<10} {r['messages']:>8} {r['signals']:>8} {r['extended']:>7} {r['multiplexed']:>5} "
              f"{r['load_s']:>7.3f} {r['frames']:>8} {r['frames_per_s']:>9} {r['values']:>9} "
              f"{r['evaluator_peak_mib']:>8} {r['violations']:>10}")
        if r["load_s"] > args.max_load_s:
            failed.append(f"{r['dbc']}: loaded in {r['load_s']} s > {args.max_load_s} s")
        if r["frames_per_s"] is not None and r["frames_per_s"] < args.min_frames_per_s:
            failed.append(f"{r['dbc']}: {r['frames_per_s']} frames/s < {args.min_frames_per_s}")
        if r["violations"] or r["max_points"] > signals.PLOT_POINTS:
            failed.append(f"{r['dbc']}: {r['violations']} violations, {r['max_points']} points (bound "
                          f"{signals.PLOT_POINTS})")
    (out / "dbc.json").write_text(json.dumps({"machine": machine_line(), "results": results,
                                              "problems": failed}, indent=2))
    for problem in failed:
        print(f"bench.dbc: {problem}", file=sys.stderr)
    print(f"bench.dbc: results in {out / 'dbc.json'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
