"""A faulty bridge: a stall whose queue overflows (first Q frames kept, released at once, the rest
dropped: losses inside the cut, excused), and the bridge publishes the first live frame twice (a duplicate:
a fault, never excused). Does the oracle still name the duplicate?"""
import syn2

B, MS = syn2.B, syn2.MS
for ids, counter in (((10, 20, 50), False), ((10, 20, 50), True), ((10, 10, 20, 20, 50, 100), False)):
    for qcap in (10, 20, 40):
        sent = syn2.build([(c, counter) for c in ids], 5000)
        stall = (B + 2000 * MS, B + 2500 * MS)
        deliv, prev, held = [], 0, 0
        for n, (t, _f) in enumerate(sent):
            ready = t + 300_000
            if stall[0] <= ready < stall[1]:
                if held >= qcap:
                    continue
                held += 1
            dep = max(ready, prev + 1000)
            if stall[0] <= ready < stall[1]:
                dep = max(dep, stall[1] + 1000)
            prev = dep
            deliv.append((dep, n))
        e = next(i for i, (a, n) in enumerate(deliv) if sent[n][0] + 300_000 >= stall[1])
        deliv.insert(e + 1, (deliv[e][0] + 1000, deliv[e][1]))   # the first live frame twice
        cut = (stall[0] - 50 * MS, stall[1] + 50 * MS)
        lost = len(sent) - len({n for _, n in deliv})
        o, n = syn2.run(sent, deliv, cut)
        print("ids", ids, "counter" if counter else "const", "queue", qcap, f"truth (0, {lost}, 1, 0)", "old", o,
              "new", n)
