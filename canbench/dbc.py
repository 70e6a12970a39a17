"""DBC files (cantools): loading one, and a frame's signals as numbers, for the recording's
/signals channels and the viewer."""
from __future__ import annotations

from pathlib import Path

import cantools


def load_dbc(path: Path | None):
    return cantools.database.load_file(str(path)) if path else None


def decode_signals(dbc, frame) -> tuple[str, dict] | None:
    """(message name, numeric signals) of a frame the DBC describes, else None."""
    try:
        message = dbc.get_message_by_frame_id(frame.can_id)
    except KeyError:
        return None
    if message.is_extended_frame != frame.extended:
        return None
    try:
        decoded = message.decode(frame.data, decode_choices=False)
    except Exception:  # a frame the DBC does not describe correctly is still recorded raw
        return None
    return message.name, {k: float(v) for k, v in decoded.items() if isinstance(v, int | float)}
