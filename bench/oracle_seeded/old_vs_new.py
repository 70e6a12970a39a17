"""Old vs new oracle on adversarial seeded runs (OLD_ORACLE, NEW_ORACLE: paths of oracle.py)."""
import os
import random
import time
from collections import Counter

import harness as H

MS, US = H.MS, H.US

OLD = H.load_oracle(os.environ["OLD_ORACLE"], "o_old")
NEW = H.load_oracle(os.environ.get("NEW_ORACLE", H.CHECKOUT_ORACLE), "o_new")


ids_n = H.draw_ids


def traffic_ids(rng, ids, dur):
    ev = []
    for i, cyc, ph, f in ids:
        k = 0
        while ph + k * cyc < dur:
            ev.append((H.BASE + ph + k * cyc + rng.randrange(200 * US), i, f(k)))
            k += 1
    ev.sort()
    return [(t // US * US, H.wire.Frame(i, len(d), d)) for t, i, d in ev]


def shape_ids(rng, shape):
    if shape == "many":
        return ids_n(rng, rng.randint(200, 300), [10, 20, 50, 100, 100, 200, 500, 1000],
                     lambda: rng.choices(("const", "counter", "slow"), (55, 20, 25))[0])
    if shape == "slowconst":  # few constant ids, cycles 50-100 ms
        return ids_n(rng, rng.randint(2, 5), [50, 100], lambda: "const")
    if shape == "counters":
        return ids_n(rng, rng.randint(2, 8), [10, 20, 50], lambda: rng.choice(("counter", "slow")))
    if shape == "one":
        return ids_n(rng, 1, [10, 20], lambda: "const")
    return None


def swap_after(delivered, rng, lo, hi, n=1):
    """Swap n pairs of neighbouring arrivals whose sent time is in [lo, hi) (a reordering bridge)."""
    return delivered


def scenario(name, seed):
    rng = random.Random(f"{name}/{seed}")
    kind, shape = name.split(":")
    t0 = 1500 * MS + rng.randrange(500 * MS)
    ids = shape_ids(rng, shape)
    if kind in ("jit_outage", "jit_outage_in"):
        length = rng.randrange(50 * MS, 2000 * MS)
    elif kind.startswith("ovf") or kind.startswith("stall"):
        length = rng.randrange(50 * MS, 3000 * MS)
    elif kind in ("bigstall", "bigstall_drain", "bigovf"):
        length = rng.randrange(2000 * MS, 6000 * MS)
    elif kind == "longovf":
        length = rng.randrange(12000 * MS, 19500 * MS)
    else:
        length = rng.randrange(50 * MS, 2000 * MS)
    tail = 3500 * MS
    if kind == "ovf2":
        gap2 = rng.randrange(300 * MS, 2500 * MS)
        length2 = rng.randrange(50 * MS, 1000 * MS)
        tail += gap2 + length2
    if kind in ("ovf_end", "outage_end"):
        tail = rng.randrange(0, 1500 * MS)
    dur = t0 + length + tail
    if shape == "bursty":
        ids = ids_n(rng, rng.randint(3, 12), [10, 20, 50, 100], lambda: rng.choice(("const", "counter", "slow")))
        sent = traffic_ids(rng, ids, dur)
        for b in range(rng.randint(1, 3)):
            cid = 0x7F0 + b
            d = rng.randbytes(8)
            per = rng.randrange(100, 500) * MS
            k = rng.randrange(per)
            while k < dur:
                for i in range(rng.randint(3, 8)):
                    sent.append(((H.BASE + k + i * 200 * US) // US * US, H.wire.Frame(cid, 8, d)))
                k += per
        sent.sort(key=lambda x: x[0])
    elif ids is None:
        sent = H.traffic(rng, shape, dur)
    else:
        sent = traffic_ids(rng, ids, dur)
    rate_gap = dur // max(1, len(sent))
    ev = (H.BASE + t0, H.BASE + t0 + length)
    window = (ev[0] - rng.randrange(100 * MS), ev[1] + rng.randrange(100 * MS))
    opts = {}
    post = None
    truth_reorder = 0

    def qsize():
        in_stall = sum(1 for t, _ in sent if ev[0] <= t + 300 * US < ev[1])
        return min(rng.randint(16, 2000), max(1, int(in_stall * rng.uniform(0.1, 0.8))))

    if kind in ("jit_outage", "jit_outage_in"):
        # a jitter spike (FIFO) before the outage, in the window's lead (or inside the window), nothing else
        if kind == "jit_outage":
            a = window[0] - rng.randrange(50 * MS, 900 * MS)
        else:
            a = ev[0] - rng.randrange(30 * MS, 400 * MS)
            window = (a - 10 * MS, window[1])
        hgt = rng.randrange(3, 90) * MS
        w = rng.randrange(1, 10) * MS
        opts = dict(lose=ev, extra=lambda t: hgt if a <= t < a + w else 0)
    elif kind in ("ovf", "ovf_end", "longovf"):
        opts = dict(stall=ev, queue=qsize())
    elif kind == "bigstall":
        opts = dict(stall=ev)
    elif kind == "bigstall_drain":
        opts = dict(stall=ev, drain=int(rate_gap / rng.uniform(1.5, 4)))
    elif kind == "bigovf":
        in_stall = sum(1 for t, _ in sent if ev[0] <= t + 300 * US < ev[1])
        opts = dict(stall=ev, queue=max(1, int(in_stall * rng.uniform(0.3, 0.9))))
    elif kind in ("ovf_dupedge", "ovf_dupin", "ovf_swapedge", "ovf_dupedge2"):
        opts = dict(stall=ev, queue=qsize())
        post = (kind, ev)
    elif kind == "ovf_oldest":  # the queue drops its oldest: the last Q frames of the stall come at its end
        q = qsize()
        inside = [n for n, (t, _) in enumerate(sent) if ev[0] <= t + 300 * US < ev[1]]
        keep_from = sent[inside[-q]][0] if inside else ev[1]
        opts = dict(lose=(ev[0] - 300 * US, keep_from), stall=(keep_from + 300 * US, ev[1]))
    elif kind == "ovf_batch":
        opts = dict(stall=ev, queue=qsize(), batch=rng.randrange(5, 51) * MS)
    elif kind in ("ovf_drop", "ovf_batch_drop", "ovf_drain_drop"):
        # a faulty bridge: after the fault settled, it drops 1-5 frames (outside every window)
        opts = dict(stall=ev, queue=qsize())
        if kind == "ovf_batch_drop":
            opts["batch"] = rng.randrange(5, 51) * MS
        if kind == "ovf_drain_drop":
            opts["drain"] = int(rate_gap / rng.uniform(1.5, 4))
        lo = window[1] + rng.randrange(1100 * MS, 2500 * MS)
        cand = [n for n, (t, _) in enumerate(sent) if lo <= t < lo + 200 * MS]
        if cand:
            k = rng.randint(1, 5)
            st = rng.randrange(len(cand))
            opts["drops"] = set(cand[st:st + k])
    elif kind == "ovf_dup":
        opts = dict(stall=ev, queue=qsize())
        lo = window[1] + rng.randrange(1100 * MS, 2500 * MS)
        cand = [n for n, (t, _) in enumerate(sent) if lo <= t < lo + 200 * MS]
        if cand:
            opts["dups"] = {rng.choice(cand)}
    elif kind == "ovf_swap":
        opts = dict(stall=ev, queue=qsize())
        lo = window[1] + rng.randrange(1100 * MS, 2500 * MS)
        post = ("swap", lo)
    elif kind == "ovf_rise":  # overflow, then latency lasting higher after the stall (nothing else lost)
        r = rng.randrange(5, 60) * MS
        opts = dict(stall=ev, queue=qsize(), extra=lambda t: r if t >= ev[1] else 0)
    elif kind == "stall_rise":  # a stall released at once, nothing lost, then a lasting rise
        r = rng.randrange(5, 60) * MS
        opts = dict(stall=ev, extra=lambda t: r if t >= ev[1] else 0)
    elif kind == "ovf2":  # two overflowing stalls in two windows close together
        ev2 = (ev[1] + gap2, ev[1] + gap2 + length2)
        opts = dict(stall=ev, queue=qsize(), lose=ev2)  # the second: an outage
        window = [window, (ev2[0] - 50 * MS, ev2[1] + 50 * MS)]
    elif kind == "outage_end":
        opts = dict(lose=ev)
    elif kind == "start":  # overflow right at the run's start
        ev = (H.BASE + rng.randrange(50 * MS, 400 * MS), H.BASE + rng.randrange(500 * MS, 1500 * MS))
        window = (ev[0] - 10 * MS, ev[1] + 10 * MS)
        opts = dict(stall=ev, queue=qsize())
    delivered = H.deliver(sent, rng, **opts)
    delivered.sort(key=lambda x: x[0])
    if post and post[0] == "swap":
        cand = [i for i in range(len(delivered) - 1) if delivered[i][1] < delivered[i + 1][1] and
                sent[delivered[i][1]][0] >= post[1] and sent[delivered[i][1]][1] != sent[delivered[i + 1][1]][1]]
        if cand:
            i = cand[0]
            (a1, n1), (a2, n2) = delivered[i], delivered[i + 1]
            delivered[i], delivered[i + 1] = (a1, n2), (a2 + 1, n1)
            truth_reorder = 1
    if post and post[0] in ("ovf_dupedge", "ovf_dupin", "ovf_swapedge", "ovf_dupedge2"):
        e = next((i for i, (a, n) in enumerate(delivered) if sent[n][0] + 400 * US >= post[1][1]), None)
        if e is not None and e > 0:
            if post[0] == "ovf_dupedge":  # the first live frame published twice
                a, n = delivered[e]
                delivered.insert(e + 1, (a + 1, n))
            elif post[0] == "ovf_dupedge2":  # the last frame of the backlog published twice
                a, n = delivered[e - 1]
                delivered.insert(e, (a + 1, n))
            elif post[0] == "ovf_dupin":
                i = rng.randrange(max(1, e))
                a, n = delivered[i]
                delivered.insert(i + 1, (a, n))
            else:
                (a1, n1), (a2, n2) = delivered[e - 1], delivered[e]
                if sent[n1][1] != sent[n2][1]:
                    delivered[e - 1], delivered[e] = (a1, n2), (a2, n1)
                    truth_reorder = 1
    return sent, delivered, window, truth_reorder


def run(oracle, sent, delivered, windows, stream=False):
    if not isinstance(windows, list):
        windows = [windows]
    sobs = [oracle.Observed(f, t, n, line=n + 1) for n, (t, f) in enumerate(sent)]
    robs = [oracle.Observed(sent[n][1], arr, i, key="vehicle/can/rx") for i, (arr, n) in enumerate(delivered)]
    t = time.process_time()
    if stream:
        c = oracle.compare_stream(iter(sobs), iter(robs), windows, keep=10**7, cuts=windows)
    else:
        c = oracle.compare(sobs, robs, windows=windows, cuts=windows)
    return c, time.process_time() - t


def truth(sent, delivered, windows):
    if not isinstance(windows, list):
        windows = [windows]
    got = Counter(n for _, n in delivered)
    dups = sum(v - 1 for v in got.values())
    lost = [n for n in range(len(sent)) if n not in got]
    # outside: approx with the rule (sent in [start - 1 s, end + settle after the first bridged after end))
    out = 0
    for n in lost:
        t = sent[n][0]
        inside = False
        for ws, we in windows:
            after = [sent[k][0] for k in got if sent[k][0] >= we]
            first = min(after) if after else None
            if ws - H.LEAD <= t and (t < we or (first is not None and t < first + H.SETTLE)):
                inside = True
        out += not inside
    return dict(lost=len(lost), lost_out=out, dups=dups)


def verdict(s):
    return (s["lost"], s["lost_in_faults"], s["duplicates"], s["reordered"])


def main():
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("configs")
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--stream", action="store_true")
    ap.add_argument("-v", action="store_true")
    a = ap.parse_args()
    for name in a.configs.split(","):
        stats = Counter()
        tt = [0.0, 0.0]
        for seed in range(a.runs):
            sent, delivered, window, tr_re = scenario(name, seed)
            tr = truth(sent, delivered, window)
            res = {}
            for label, o in (("old", OLD), ("new", NEW)):
                c, dt = run(o, sent, delivered, window)
                tt[label == "new"] += dt
                res[label] = c.summary()
            vo, vn = verdict(res["old"]), verdict(res["new"])
            want = (tr["lost_out"], tr["lost"] - tr["lost_out"], tr["dups"], tr_re)
            # verdict level: lost outside > 0? duplicates > 0? reordered > 0?
            fl = lambda v: (v[0] > 0, v[2] > 0, v[3] > 0)  # noqa: E731
            ok_o, ok_n = fl(vo) == fl(want), fl(vn) == fl(want)
            ex_o, ex_n = vo == want, vn == want
            stats["flag_old"] += ok_o
            stats["flag_new"] += ok_n
            stats["exact_old"] += ex_o
            stats["exact_new"] += ex_n
            anyf = lambda v: v[0] > 0 or v[2] > 0 or v[3] > 0  # noqa: E731
            if anyf(want) and not anyf(vo):
                stats["hid_old"] += 1
            if anyf(want) and not anyf(vn):
                stats["HID_NEW"] += 1
                if anyf(vo):
                    stats["HID_REGRESS"] += 1
                    print(f"  HIDDEN {name} {seed}: want {want} old {vo} new {vn}")
            if not anyf(want) and anyf(vo):
                stats["ff_old"] += 1
            if not anyf(want) and anyf(vn):
                stats["FF_NEW"] += 1
            if ok_o and not ok_n:
                stats["FLAG_REGRESS"] += 1
            if ex_o and not ex_n:
                stats["exact_regress"] += 1
            if a.stream:
                cs, _ = run(NEW, sent, delivered, window, stream=True)
                if verdict(cs.summary()) != vn or cs.summary()["latency"] != res["new"]["latency"]:
                    stats["STREAM_DIFF"] += 1
                    print(f"  STREAM {name} {seed}: {verdict(cs.summary())} vs {vn}")
            if a.v and (vo != vn or not ex_n):
                mark = "REG" if ok_o and not ok_n else ("reg" if ex_o and not ex_n else "")
                print(f"  {name} {seed}: want {want} old {vo} lat {res['old']['latency']['max_ms']:.1f} "
                      f"new {vn} lat {res['new']['latency']['max_ms']:.1f} {mark}")
        print(f"{name:22s} verdict-flags old {stats['flag_old']}/{a.runs} new {stats['flag_new']}  exact old "
              f"{stats['exact_old']} new {stats['exact_new']}  FLAG_REGRESS {stats['FLAG_REGRESS']} exact_regress "
              f"{stats['exact_regress']} hid o/n {stats['hid_old']}/{stats['HID_NEW']} ff o/n {stats['ff_old']}/"
              f"{stats['FF_NEW']} stream_diff {stats['STREAM_DIFF']}  cpu old {tt[0]:.1f} new {tt[1]:.1f}",
              flush=True)


if __name__ == "__main__":
    main()
