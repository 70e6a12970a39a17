"""Put order as the bridge keeps it (Zenoh -> CAN): commands that wait together leave in CAN
arbitration order (docs/bridge.md), so a command overtaken only by ones of higher priority is in
order. One rule for the verdict (checks.zenoh_to_can) and the counts metrics.json and the report
show (analysis), so the two never disagree."""
from __future__ import annotations

from typing import Any


def overtaken_commands(matched) -> list[tuple]:
    """(command, a command put after it that the bus carried first and that has no higher CAN
    priority) for each command out of put order. Waiting together, a command of higher priority
    goes first (the bridge's order, docs/bridge.md), so only such overtakers are in order; every
    overtaker is looked at, not only the latest put (a Fenwick tree of the highest arbitration key
    over later puts). matched: (command, bus frame) in bus order."""
    order = sorted({s.index for s, _ in matched})
    slot = {index: len(order) - i for i, index in enumerate(order)}  # 1-based, later puts first
    tree: list[tuple[int, Any] | None] = [None] * (len(order) + 1)
    out = []
    for s, _ in matched:
        key = arbitration_key(s.frame)
        worst, i = None, slot[s.index] - 1  # the carried commands put after s: slots before its own
        while i > 0:
            if tree[i] is not None and (worst is None or tree[i][0] > worst[0]):  # type: ignore[index]
                worst = tree[i]
            i -= i & -i
        if worst is not None and worst[0] >= key:
            out.append((s, worst[1]))
        i = slot[s.index]
        while i < len(tree):
            if tree[i] is None or tree[i][0] < key:  # type: ignore[index]
                tree[i] = (key, s)
            i += i & -i
    return out


def arbitration_key(f) -> int:
    """A frame's place in CAN arbitration, lower wins (11-bit base id, then standard before extended,
    data before remote): the order the bridge takes waiting commands in (zn_tx_arbitration_key)."""
    if not f.extended:
        return (f.can_id & 0x7FF) << 21 | int(f.remote) << 20
    return (f.can_id >> 18 & 0x7FF) << 21 | 1 << 20 | 1 << 19 | (f.can_id & 0x3FFFF) << 1 | int(f.remote)
