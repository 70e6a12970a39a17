"""Seeded runs with a known truth for the oracle (overflowing stall + guards)."""
from __future__ import annotations

import importlib.util
import os
import random
import sys
import time
from collections import deque

from canbench import wire  # noqa: E402
from canbench.distribution import Distribution  # noqa: E402

MS, US = 1_000_000, 1_000
BASE = 1_700_000_000_000_000_000
LEAD = SETTLE = 1_000_000_000


# the oracle of this checkout (NEW_ORACLE in the comparing scripts overrides it)
CHECKOUT_ORACLE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../canbench/oracle.py")


def load_oracle(path, name):
    spec = importlib.util.spec_from_file_location("canbench." + name, path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "canbench"
    sys.modules["canbench." + name] = mod
    spec.loader.exec_module(mod)
    return mod


# ---------------------------------------------------------------- traffic
def content(rng, kind, dlc):
    if kind == "const":
        d = rng.randbytes(dlc)
        return lambda k: d
    if kind == "counter":
        d = bytearray(rng.randbytes(dlc))
        mod = rng.choice((4, 8, 16, 256))

        def f(k):
            x = bytearray(d)
            x[0] = k % mod
            x[-1] = sum(x[:-1]) & 0xFF
            return bytes(x)
        return f
    d = bytearray(rng.randbytes(dlc))
    every = rng.randint(5, 100)
    start = rng.randrange(256)

    def g(k):
        x = bytearray(d)
        x[1 % dlc] = (start + k // every) & 0xFF
        return bytes(x)
    return g


def make_ids(rng, shape):
    if shape == "car":
        n = rng.randint(10, 60)
        cycles = [10, 20, 20, 50, 100, 100, 200, 500, 1000]
        kinds = lambda: rng.choices(("const", "counter", "slow"), (55, 20, 25))[0]  # noqa: E731
    else:
        n = rng.randint(2, 5)
        cycles = [10, 20, 50, 100]
        kinds = (lambda: "const") if shape == "fewconst" else \
            (lambda: rng.choices(("const", "counter", "slow"), (50, 25, 25))[0])
    return draw_ids(rng, n, cycles, kinds)


def draw_ids(rng, n, cycles, kinds):
    """n distinct 11-bit ids, each with its cycle, phase and content of kind kinds()."""
    ids = []
    used = set()
    for _ in range(n):
        i = rng.randrange(0x7FF)
        while i in used:
            i = rng.randrange(0x7FF)
        used.add(i)
        cyc = rng.choice(cycles)
        dlc = rng.choice((8, 8, 8, 4, 2))
        ids.append((i, cyc * MS, rng.randrange(cyc * MS), content(rng, kinds(), dlc)))
    return ids


def traffic(rng, shape, dur_ns):
    ev = []
    for i, cyc, ph, f in make_ids(rng, shape):
        k = 0
        while ph + k * cyc < dur_ns:
            t = BASE + ph + k * cyc + rng.randrange(200 * US)
            ev.append((t, i, f(k)))
            k += 1
    ev.sort()
    return [(t // US * US, wire.Frame(i, len(d), d)) for t, i, d in ev]


# ---------------------------------------------------------------- delivery
def deliver(sent, rng, *, stall=None, queue=None, drain=None, lose=None, lose2=None, extra=None, batch=None, dups=(),
            stall2=None, drops=()):
    """sent: [(t, frame)]. Returns [(arrival, sent index)] in arrival order (a FIFO link)."""
    out = []
    prev = 0
    deps = deque()
    for n, (t, _f) in enumerate(sent):
        if (lose and lose[0] <= t < lose[1]) or (lose2 and lose2[0] <= t < lose2[1]) or n in drops:
            continue
        ready = t + 300 * US + rng.randrange(50 * US) + (extra(t) if extra else 0)
        while deps and deps[0] <= ready:
            deps.popleft()
        if queue is not None and stall and stall[0] <= ready and len(deps) >= queue:
            continue  # the bridge's queue is full: dropped
        gap = US
        if drain and stall and ready >= stall[0] and (ready < stall[1] or prev > ready):
            gap = drain
        dep = max(ready, prev + gap)
        if stall and stall[0] <= ready < stall[1]:
            dep = max(dep, stall[1] + US)
        if stall2 and stall2[0] <= dep < stall2[1]:
            dep = stall2[1] + US
        prev = dep
        deps.append(dep)
        arr = -(-dep // batch) * batch if batch else dep
        out.append((arr, n))
        if n in dups:
            out.append((arr + (0 if batch else US), n))
            prev += US
    return out


# ---------------------------------------------------------------- truth and check
def truth_of(sent, delivered, window):
    """The truth, twice: the true copies, and the canonical one (within a run of identical
    back-to-back frames the delivered copies are the run's first ones: nothing tells them apart).
    Lost frames compare as runs; latency and split may be either's (or in between)."""
    run_of = []
    for n, (_t, f) in enumerate(sent):
        run_of.append(run_of[-1] if n and sent[n - 1][1] == f else n)
    seen = {}
    true, canon = [], []
    dupcount = 0
    got = set()
    for arr, n in delivered:
        if n in got:
            dupcount += 1
            continue
        got.add(n)
        r = run_of[n]
        k = seen.get(r, r)
        seen[r] = k + 1
        canon.append((arr, k))
        true.append((arr, n))
    out = {"dups": dupcount, "run_of": run_of}
    for name, pairs in (("true", true), ("canon", canon)):
        matched = {k for _, k in pairs}
        lost = [n for n in range(len(sent)) if n not in matched]
        lat = Distribution()
        for arr, k in pairs:
            lat.add((arr - sent[k][0]) / 1e6)
        ws, we = window
        after = [sent[k][0] for _, k in pairs if sent[k][0] >= we]
        hi = min(after) + SETTLE if after else we
        inf = [n for n in lost if ws - LEAD <= sent[n][0] < hi]
        out[name] = {"lost": lost, "split": (len(lost) - len(inf), len(inf)), "lat": lat.stats()}
    return out


def check(oracle, sent, delivered, window, stream=False):
    sobs = [oracle.Observed(f, t, n, line=n + 1) for n, (t, f) in enumerate(sent)]
    robs = [oracle.Observed(sent[n][1], arr, i, key="vehicle/can/rx") for i, (arr, n) in enumerate(delivered)]
    tr = truth_of(sent, delivered, window)
    if stream:
        c = oracle.compare_stream(iter(sobs), iter(robs), [window], keep=10**7, cuts=[window])
    else:
        c = oracle.compare(sobs, robs, windows=[window], cuts=[window])
    s = c.summary()
    run_of = tr["run_of"]
    lost = sorted(run_of[o.index] for o in c.lost + c.lost_in_faults)
    want = sorted(run_of[n] for n in tr["true"]["lost"])
    bad = []
    if lost != want:
        from collections import Counter
        bad.append(f"lost {len(lost)} vs {len(want)} (wrong {sum((Counter(lost) - Counter(want)).values())})")
    split = (s["lost"], s["lost_in_faults"])
    if split not in (tr["true"]["split"], tr["canon"]["split"]):
        bad.append(f"split {split} vs {tr['true']['split']}")
    if s["duplicates"] != tr["dups"]:
        bad.append(f"dups {s['duplicates']} vs {tr['dups']}")
    if s["reordered"]:
        bad.append(f"reordered {s['reordered']}")
    for q in ("max_ms", "p50_ms"):
        a, b1, b2 = s["latency"][q], tr["true"]["lat"][q], tr["canon"]["lat"][q]
        lo, hi = min(b1, b2), max(b1, b2)
        if a is None or a < lo - 2 - 0.02 * lo or a > hi + 2 + 0.02 * hi:
            bad.append(f"{q} {a} vs {b1}")
    return bad, s


# ---------------------------------------------------------------- configurations
def scenario(name, seed):
    rng = random.Random(f"{name}/{seed}")
    kind, shape = name.split(":")
    t0 = 1500 * MS + rng.randrange(500 * MS)
    opts = {}
    if kind in ("overflow", "overflow_drain", "overflow_batch", "stall", "stall_drain", "dupbacklog", "stall_batch",
                "stall2", "drain_slow", "overflow_noise"):
        length = rng.randrange(50 * MS, 3000 * MS) if kind.startswith("overflow") else rng.randrange(20 * MS, 500 * MS)
    elif kind.startswith("outage") or kind == "stall_outage":
        length = rng.randrange(5 * MS, 2000 * MS) if kind != "stall_outage" else rng.randrange(150 * MS, 2000 * MS)
    else:
        length = rng.randrange(50 * MS, 400 * MS)
    dur = t0 + length + 3500 * MS
    sent = traffic(rng, shape, dur)
    rate_gap = dur // max(1, len(sent))
    ev = (BASE + t0, BASE + t0 + length)
    if kind.startswith("overflow"):
        in_stall = sum(1 for t, _ in sent if ev[0] <= t + 300 * US < ev[1])
        q = rng.randint(16, 2000)
        q = min(q, max(1, int(in_stall * rng.uniform(0.1, 0.8))))
        opts = dict(stall=ev, queue=q)
        if kind == "overflow_drain":
            opts["drain"] = int(rate_gap / rng.uniform(1.5, 4))
    elif kind in ("stall", "dupbacklog"):
        opts = dict(stall=ev)
        if kind == "dupbacklog":
            inside = [n for n, (t, _) in enumerate(sent) if ev[0] <= t < ev[1]]
            if inside:
                opts["dups"] = {rng.choice(inside)}
    elif kind == "stall_drain":
        opts = dict(stall=ev, drain=int(rate_gap / rng.uniform(1.5, 4)))
    elif kind in ("outage", "outage_batch"):
        opts = dict(lose=ev)
        if kind == "outage_batch":
            opts["batch"] = rng.randrange(5, 51) * MS
    elif kind == "jitter":
        spikes = [(ev[0] + rng.randrange(length), rng.randrange(1, 81) * MS, rng.randrange(1, 30) * MS)
                  for _ in range(rng.randint(1, 6))]
        opts = dict(extra=lambda t: max([h for a, h, w in spikes if a <= t < a + w], default=0))
    elif kind == "rise":  # rises to R and is worked off at its pace, before the settling
        r = rng.randrange(15, 101) * MS
        opts = dict(extra=lambda t: int(r * (1 - abs(2 * (t - ev[0]) / length - 1))) if ev[0] <= t < ev[1] else 0)
    elif kind == "plateau":  # a standing latency that ends in a burst
        p = rng.randrange(10, 81) * MS
        opts = dict(extra=lambda t: p if ev[0] <= t < ev[1] else 0)
    elif kind == "outage2":  # two outages close together
        mid = ev[0] + length // 3
        gap2 = rng.randrange(50 * MS, 300 * MS)
        opts = dict(lose=(ev[0], mid), lose2=(mid + gap2, ev[1] + gap2))
        ev = (ev[0], ev[1] + gap2)
    elif kind == "outage_jitter":
        spikes = [(ev[1] + rng.randrange(300 * MS), rng.randrange(1, 81) * MS, rng.randrange(1, 30) * MS)
                  for _ in range(rng.randint(1, 4))]
        opts = dict(lose=ev, extra=lambda t: max([h for a, h, w in spikes if a <= t < a + w], default=0))
    elif kind == "outage_backlog":  # an outage, then a short backlog released at once
        b = ev[1] + rng.randrange(20 * MS, 200 * MS)
        opts = dict(lose=ev, stall=(b, b + rng.randrange(20 * MS, 100 * MS)))
    elif kind == "stall_outage":  # a stall released at once, then an outage right after
        s1 = ev[0] + rng.randrange(20 * MS, 100 * MS)
        opts = dict(stall=(ev[0], s1), lose=(s1 + rng.randrange(1 * MS, 20 * MS), ev[1]))
    elif kind == "lastrise":  # a rise that lasts past the settling (a known limit)
        r = rng.randrange(15, 101) * MS
        opts = dict(extra=lambda t: r if t >= ev[0] else 0)
    elif kind == "blip":  # a reconnect losing 0.5-2 ms
        opts = dict(lose=(ev[0], ev[0] + rng.randrange(500 * US, 2 * MS)))
    elif kind == "stall_batch":
        opts = dict(stall=ev, batch=rng.randrange(5, 51) * MS)
    elif kind == "overflow_batch":
        in_stall = sum(1 for t, _ in sent if ev[0] <= t + 300 * US < ev[1])
        q = min(rng.randint(16, 2000), max(1, int(in_stall * rng.uniform(0.1, 0.8))))
        opts = dict(stall=ev, queue=q, batch=rng.randrange(5, 51) * MS)
    elif kind == "stall2":  # a stall released in two parts
        opts = dict(stall=ev, stall2=(ev[1] + rng.randrange(5 * MS, 50 * MS), ev[1] + rng.randrange(60 * MS, 200 * MS)))
    elif kind == "drain_slow":  # a backlog drained at about the bus's rate, nothing lost
        opts = dict(stall=ev, drain=int(rate_gap / rng.uniform(1.05, 1.3)))
    elif kind == "jitterburst":  # 0-80 ms of jitter on every frame for a while
        top = rng.randrange(1, 81) * MS
        opts = dict(extra=lambda t: rng.randrange(top) if ev[0] <= t < ev[1] else 0)
    elif kind in ("outage_noise", "overflow_noise"):  # single drops and duplicates elsewhere
        if kind == "outage_noise":
            opts = dict(lose=ev)
        else:
            in_stall = sum(1 for t, _ in sent if ev[0] <= t + 300 * US < ev[1])
            opts = dict(stall=ev, queue=min(rng.randint(16, 2000), max(1, int(in_stall * rng.uniform(0.1, 0.8)))))
        far = [n for n, (t, _) in enumerate(sent) if t < ev[0] - 1500 * MS or t > ev[1] + 1500 * MS]
        opts["drops"] = set(rng.sample(far, min(len(far), rng.randint(1, 4))))
        opts["dups"] = set(rng.sample(far, min(len(far), rng.randint(0, 3)))) - opts["drops"]
    if kind == "outage_stop":  # an outage after which a third of the contents stop
        ids = sorted({f.can_id for _, f in sent})
        stop = set(rng.sample(ids, max(1, len(ids) // 3)))
        sent = [(t, f) for t, f in sent if not (f.can_id in stop and t >= ev[1])]
        opts = dict(lose=ev)
    delivered = deliver(sent, rng, **opts)
    delivered.sort(key=lambda x: x[0])
    window = (ev[0] - rng.randrange(100 * MS), ev[1] + rng.randrange(100 * MS))
    return sent, delivered, window


CONFIGS = ["overflow:car", "overflow:fewconst", "overflow:fewmixed",
           "overflow_drain:car", "overflow_drain:fewconst", "overflow_drain:fewmixed",
           "outage:car", "outage:fewconst", "outage_batch:car",
           "stall:car", "stall:fewconst", "stall:fewmixed",
           "stall_drain:car", "stall_drain:fewconst", "stall_drain:fewmixed",
           "jitter:car", "jitter:fewconst", "jitter:fewmixed",
           "rise:car", "rise:fewconst", "rise:fewmixed",
           "plateau:car", "plateau:fewconst", "plateau:fewmixed",
           "dupbacklog:car", "dupbacklog:fewconst", "dupbacklog:fewmixed",
           "outage:fewmixed", "outage_batch:fewconst", "outage_batch:fewmixed",
           "outage2:fewconst", "outage2:car", "outage_jitter:fewconst", "outage_jitter:car",
           "outage_backlog:fewconst", "outage_backlog:car", "stall_outage:fewconst", "stall_outage:car",
           "blip:car", "blip:fewconst", "stall_batch:car", "stall_batch:fewconst",
           "lastrise:car", "lastrise:fewconst", "lastrise:fewmixed",
           "overflow_batch:car", "overflow_batch:fewconst",
           "stall2:car", "stall2:fewconst", "drain_slow:car", "drain_slow:fewconst", "jitterburst:car",
           "jitterburst:fewconst", "jitterburst:fewmixed", "outage_noise:car", "outage_noise:fewmixed",
           "overflow_noise:car", "overflow_noise:fewmixed"]


def main():
    import argparse
    import json
    ap = argparse.ArgumentParser()
    ap.add_argument("--oracle", default=CHECKOUT_ORACLE)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--stream", action="store_true")
    ap.add_argument("--out")
    ap.add_argument("-v", action="store_true")
    a = ap.parse_args()
    oracle = load_oracle(a.oracle, "oracle_h")
    result = {}
    for name in a.configs.split(","):
        ok = []
        t = time.process_time()
        for seed in range(a.runs):
            sent, delivered, window = scenario(name, seed)
            bad, _ = check(oracle, sent, delivered, window)
            if a.stream and not bad:
                bad2, _ = check(oracle, sent, delivered, window, stream=True)
                bad = ["stream: " + b for b in bad2]
            if not bad:
                ok.append(seed)
            elif a.v:
                print(f"  {name} seed {seed}: {'; '.join(bad)}")
        result[name] = ok
        print(f"{name:24s} {len(ok):3d}/{a.runs}  ({time.process_time() - t:.1f} s)", flush=True)
    if a.out:
        json.dump(result, open(a.out, "w"))


if __name__ == "__main__":
    main()
