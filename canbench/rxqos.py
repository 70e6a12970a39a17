"""The bridge's CAN -> Zenoh QoS table (`bridge.rx_qos`, zenoh-node --rx-qos): the same grammar
and refusals as the bridge's parser (firmware/components/zenoh-node/include/zn_qos.h), so a
scenario with a table the bridge would refuse fails validation with its file:line, and the oracle
knows which frames share a class (order is kept per class, not across classes).

    0x000-0x0FF:realtime,express;0x100-0x7FF:data,best-effort;e:18DA0000-18DAFFFF:background,drop
"""
from __future__ import annotations

from dataclasses import dataclass

PRIORITIES = ("realtime", "interactive-high", "interactive-low", "data-high", "data", "data-low", "background")
FLAGS = {"express": ("express", True), "best-effort": ("best_effort", True), "reliable": ("best_effort", False),
         "drop": ("drop", True), "block": ("drop", False)}
FIELD_NAMES = {"priority": "priority", "express": "express flag",
               "best_effort": "reliability (best-effort or reliable)", "drop": "congestion control (drop or block)"}
MAX_CLASSES, MAX_RULES = 8, 16
STD_MAX, EXT_MAX = 0x7FF, 0x1FFFFFFF


@dataclass(frozen=True)
class Qos:
    priority: int = 5   # Zenoh's 1 (realtime) .. 7 (background)
    express: bool = False
    best_effort: bool = False
    drop: bool = False

    def __str__(self) -> str:
        return ",".join([PRIORITIES[self.priority - 1], *(["express"] if self.express else []),
                         "drop" if self.drop else "block", "best-effort" if self.best_effort else "reliable"])


@dataclass(frozen=True)
class Rule:
    first: int
    last: int
    extended: bool
    qos: Qos


class QosTableError(ValueError):
    """A table the bridge refuses: the message is the bridge's reason."""


def _id(text: str, whole: str) -> int:
    t = text.strip()
    digits = t[2:] if t[:2].lower() == "0x" else t
    if not 1 <= len(digits) <= 8 or any(c not in "0123456789abcdefABCDEF" for c in digits):
        raise QosTableError(f"id range '{whole}' is not HEX or HEX-HEX (prefix e: for 29-bit ids)")
    return int(digits, 16)


def _range(text: str) -> tuple[int, int, bool]:
    extended = text.startswith("e:")
    body = text[2:] if extended else text
    first_text, dash, last_text = body.partition("-")
    first = _id(first_text, text)
    last = _id(last_text, text) if dash else first
    top = EXT_MAX if extended else STD_MAX
    if first > top or last > top:
        raise QosTableError(f"id range '{text}' is beyond 0x{top:X} "
                            f"({'29 bits' if extended else '11 bits; prefix e: for 29-bit ids'})")
    if first > last:
        raise QosTableError(f"id range '{text}' is empty (first above last)")
    return first, last, extended


def _items(text: str, base: Qos) -> Qos:
    fields = {"priority": base.priority, "express": base.express, "best_effort": base.best_effort, "drop": base.drop}
    named: set[str] = set()
    for raw in text.split(","):
        word = raw.strip()
        if not word:
            raise QosTableError(f"an empty QoS item in '{text}'")
        if word in PRIORITIES:
            field, value = "priority", PRIORITIES.index(word) + 1
        elif word in FLAGS:
            field, value = FLAGS[word]
        else:
            raise QosTableError(f"'{word}' is not a priority ({', '.join(PRIORITIES)}) or a flag "
                                f"({', '.join(FLAGS)})")
        if field in named:
            raise QosTableError(f"'{word}' names the {FIELD_NAMES[field]} a second time")
        named.add(field)
        fields[field] = value
    return Qos(**fields)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Table:
    rules: tuple[Rule, ...]
    default: Qos

    @property
    def classes(self) -> list[Qos]:
        """The distinct QoS, highest priority first (the order the bridge serves them)."""
        seen = list(dict.fromkeys([*(r.qos for r in self.rules), self.default]))
        return sorted(seen, key=lambda q: q.priority)

    def class_of(self, can_id: int, extended: bool) -> Qos:
        for r in self.rules:
            if r.extended == extended and r.first <= can_id <= r.last:
                return r.qos
        return self.default


def parse(text: str, base: Qos = Qos()) -> Table:
    """The table over the bridge's default QoS base; QosTableError with the bridge's reason."""
    try:
        return _parse(text, base)
    except QosTableError as e:
        raise QosTableError(f"rx QoS table: {e}") from None


def _parse(text: str, base: Qos) -> Table:
    rules: list[Rule] = []
    body = text.strip()
    if body:
        parts = body.split(";")
        for i, raw in enumerate(parts):
            rule = raw.strip()
            if not rule:
                raise QosTableError("an empty rule after the last ';'" if i == len(parts) - 1 and i
                                    else "an empty rule (a ';' too many?)")
            head = 2 if rule.startswith("e:") else 0
            colon = rule.find(":", head)
            if colon < 0:
                raise QosTableError(f"rule '{rule}' is not RANGE:QOS (e.g. 0x000-0x0FF:realtime,express)")
            if len(rules) == MAX_RULES:
                raise QosTableError(f"more than {MAX_RULES} rules")
            first, last, extended = _range(rule[:colon].strip())
            items = rule[colon + 1:].strip()
            if not items:
                raise QosTableError(f"rule '{rule}' names no QoS after ':'")
            qos = _items(items, base)
            for o in rules:
                if o.extended == extended and first <= o.last and o.first <= last:
                    e = "e:" if extended else ""
                    raise QosTableError(f"{e}0x{first:X}-0x{last:X} overlaps {e}0x{o.first:X}-0x{o.last:X} "
                                        "(a frame must have one QoS)")
            rules.append(Rule(first, last, extended, qos))
    table = Table(tuple(rules), base)
    if len(table.classes) > MAX_CLASSES:
        raise QosTableError(f"more than {MAX_CLASSES} distinct QoS classes (the default, rx_qos, included)")
    return table


def base_of(bridge: dict) -> Qos:
    """The default QoS a scenario's bridge keys give (rx_priority, rx_congestion; reliable)."""
    return Qos(priority=int(bridge.get("rx_priority", 5)), drop=bridge.get("rx_congestion") == "drop")


def of_bridge(bridge: dict) -> Table | None:
    """The scenario's table when it has more than one class, else None (one order for all frames)."""
    text = bridge.get("rx_qos") or ""
    if not text:
        return None
    table = parse(text, base_of(bridge))
    return table if len(table.classes) > 1 else None


def reordered_per_class(matched, table: Table) -> list:
    """(frame, the frame of its class it arrived after) for frames that arrived after a frame of
    their own QoS class sent later: the oracle's reordering, judged within each class only."""
    latest: dict[Qos, object] = {}
    out = []
    for s, _ in sorted(matched, key=lambda p: p[1].index):
        cls = table.class_of(s.frame.can_id, s.frame.extended)
        p = latest.get(cls)
        if p is not None and s.index < p.index:  # type: ignore[attr-defined]
            out.append((s, p))
        if p is None or s.index > p.index:  # type: ignore[attr-defined]
            latest[cls] = s
    return out
