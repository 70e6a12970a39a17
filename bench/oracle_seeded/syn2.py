"""Correct bridges (nothing lost) that the new oracle fails. A: a 2 s stall released at once on a busy bus
(backlog > DOUBT_FRAMES). B: 2 constant ids, a 100 ms stall released at once, then latency lasting +R ms."""
import os
import sys

import harness as H

from canbench import wire

MS = 1_000_000
B = 1_700_000_000_000_000_000
OLD = H.load_oracle(os.environ["OLD_ORACLE"], "yold")
NEW = H.load_oracle(os.environ.get("NEW_ORACLE", H.CHECKOUT_ORACLE), "ynew")


def build(ids, dur_ms):
    sent = []
    for j, (cyc, counter) in enumerate(ids):
        for k in range(dur_ms // cyc):
            t = B + k * cyc * MS + (j * 137 % 1000) * 10_000 + (k * 37 % 11) * 10_000
            d = bytes([j, k % 16 if counter else 0] + [7] * 6)
            sent.append((t, wire.Frame(0x100 + j, 8, d)))
    sent.sort(key=lambda x: x[0])
    return sent


def deliver(sent, stall, rise_ms=0):
    deliv, prev = [], 0
    for n, (t, _f) in enumerate(sent):
        ready = t + 300_000 + (rise_ms * MS if t >= stall[1] else 0)
        dep = max(ready, prev + 1000)
        if stall[0] <= ready < stall[1]:
            dep = max(dep, stall[1] + 1000)
        prev = dep
        deliv.append((dep, n))
    return deliv


def run(sent, deliv, cut):
    out = []
    for o in (OLD, NEW):
        so = [o.Observed(f, t, n, line=n + 1) for n, (t, f) in enumerate(sent)]
        ro = [o.Observed(sent[n][1], a, i, key="k") for i, (a, n) in enumerate(deliv)]
        s = o.compare(so, ro, windows=[cut], cuts=[cut]).summary()
        s2 = o.compare_stream(iter(so), iter(ro), [cut], keep=10**6, cuts=[cut]).summary()
        v = (s["lost"], s["lost_in_faults"], s["duplicates"], s["reordered"], round(s["latency"]["max_ms"], 1))
        v2 = (s2["lost"], s2["lost_in_faults"], s2["duplicates"], s2["reordered"], round(s2["latency"]["max_ms"], 1))
        out.append(v if v == v2 else (v, "stream", v2))
    return out


if __name__ == "__main__":
    which = sys.argv[1]
    if which == "A":
        for n_ids, stall_ms in ((40, 2000), (40, 1000), (20, 2000), (60, 3000)):
            sent = build([(10, j % 3 == 0) for j in range(n_ids)], 9000)
            stall = (B + 3000 * MS, B + (3000 + stall_ms) * MS)
            deliv = deliver(sent, stall)
            deliv.sort()
            cut = (stall[0] - 50 * MS, stall[1] + 50 * MS)
            backlog = sum(1 for t, _ in sent if stall[0] <= t + 300_000 < stall[1])
            print("A", n_ids, "ids @10ms, stall", stall_ms, "backlog", backlog,
                  "old/new (lost, in_faults, dup, reord, lat max)", run(sent, deliv, cut),
                  f"truth (0,0,0,0,{stall_ms})")
    else:
        for rise in (12, 15, 25, 40):
            for st in (60, 100, 300):
                sent = build([(10, False), (20, False)], 6000)
                stall = (B + 2000 * MS, B + (2000 + st) * MS)
                deliv = deliver(sent, stall, rise)
                deliv.sort()
                cut = (stall[0] - 50 * MS, stall[1] + 50 * MS)
                o, n = run(sent, deliv, cut)
                print("B rise", rise, "stall", st, "old", o, "new", n, "" if o == n else "DIFF")
