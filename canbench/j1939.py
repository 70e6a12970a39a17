"""J1939 addressing (SAE J1939-21) of 29-bit ids: a frame's parameter group (PGN), and what an
ECU of a DBC id receives of its group. A DBC names one id per message, its usual sender
(source address), priority and, for a PDU1 group, destination; a truck's network sends a group
from other sources and at other priorities (dbc.message_of, the responder's filters)."""
from __future__ import annotations

# PDU formats whose data means what its sender makes it mean, so another source's frame is not the
# DBC's message: proprietary A (EF) and B (FF), and ISO 15765-2 (UDS) on 29 bits (DA, DB)
BY_SENDER = frozenset({0xEF, 0xFF, 0xDA, 0xDB})


def group_of(can_id: int) -> int | None:
    """The J1939 parameter group number of a 29-bit id (a PDU1 group's destination is not part
    of it), None for a group whose meaning is its sender's (BY_SENDER) or an id past 29 bits."""
    if can_id > 0x1FFFFFFF:
        return None
    pdu_format = (can_id >> 16) & 0xFF
    if pdu_format in BY_SENDER:
        return None
    return (can_id >> 8) & (0x3FFFF if pdu_format >= 240 else 0x3FF00)


GLOBAL = 0xFF  # a PDU1 destination: every ECU


def group_filters(can_id: int) -> list[tuple[int, int]]:
    """(id, mask) socket filters that pass what an ECU of this J1939 id receives of its group:
    from any source, at any priority; a PDU1 group only to the id's destination or to global."""
    mask = 0x03FFFF00  # the data pages, the PDU format and its specific; not priority or source
    if (can_id >> 16) & 0xFF >= 240:
        return [(can_id, mask)]
    return [(can_id, mask), ((can_id & ~0xFF00) | GLOBAL << 8, mask)]


def addressed(dbc_id: int, can_id: int) -> bool:
    """Whether a frame of a J1939 group is for the ECU of dbc_id: any PDU2 frame, a PDU1 frame
    to its destination or to global (a request to the brakes is not the engine's to answer)."""
    if (dbc_id >> 16) & 0xFF >= 240:
        return True
    return (can_id >> 8) & 0xFF in ((dbc_id >> 8) & 0xFF, GLOBAL)
