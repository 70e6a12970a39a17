"""A merely late frame near a cut, then a real outage in the same window (the first review's
regression: the late frame's doubt held the outage's own off): old and new oracle side by side."""
import os

import harness as H

from canbench import wire

MS = 1_000_000
B = 1_700_000_000_000_000_000
OLD = H.load_oracle(os.environ["OLD_ORACLE"], "xold")
NEW = H.load_oracle(os.environ.get("NEW_ORACLE", H.CHECKOUT_ORACLE), "xnew")
def case(jt, delay, out=(3100, 3600), cycles=(100, 30, 70, 110, 50)):
    sent = []
    for j, cyc in enumerate(cycles):
        for k in range(8000 // cyc):
            t = B + k * cyc * MS + j * 7 * MS + (k * 37 % 11) * 10_000
            sent.append((t, wire.Frame(0x100 + j, 8, bytes([j] * 8))))
    sent.sort(key=lambda x: x[0])
    deliv, prev = [], 0
    jn = min(range(len(sent)), key=lambda n: abs(sent[n][0] - B - jt * MS))
    for n, (t, _f) in enumerate(sent):
        if B + out[0] * MS <= t < B + out[1] * MS:
            continue
        ready = t + 300_000 + (delay * MS if n == jn else 0)
        prev = max(ready, prev + 1000)
        deliv.append((prev, n))
    cut = (B + 3000 * MS, B + 3800 * MS)
    res = []
    for o in (OLD, NEW):
        so = [o.Observed(f, t, n, line=n + 1) for n, (t, f) in enumerate(sent)]
        ro = [o.Observed(sent[n][1], a, i, key="k") for i, (a, n) in enumerate(deliv)]
        s = o.compare(so, ro, windows=[cut], cuts=[cut]).summary()
        res.append((s["lost"], s["lost_in_faults"], s["duplicates"], s["reordered"], round(s["latency"]["max_ms"], 1)))
    return sent[jn][1].can_id, res
if __name__ == "__main__":
    for jt in range(2050, 3000, 50):
        for delay in (20, 40, 60, 80):
            cid, (o, n) = case(jt, delay)
            if o != n:
                print(jt, delay, hex(cid), "old", o, "new", n)
