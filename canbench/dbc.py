"""DBC files (cantools): loading one (cached per file and mtime, so a scenario's buses and its
checks share one database), a frame's signals as numbers (the recording's /signals channels,
the viewer, the signal expectations), a message's database cycle time and send type, and why a
scenario's value cannot be a signal's."""
from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import cantools


@lru_cache(maxsize=16)
def _load(path: str, mtime_ns: int):
    return cantools.database.load_file(path)


def load_dbc(path: Path | None):
    """The cantools database of a DBC file (None for None); cantools' own error on a bad file."""
    return _load(str(path), Path(path).stat().st_mtime_ns) if path else None


def message_of(dbc, frame):
    """The DBC's message of a frame (id and 11/29-bit as the DBC has them), else None."""
    try:
        message = dbc.get_message_by_frame_id(frame.can_id)
    except KeyError:
        return None
    return message if message.is_extended_frame == frame.extended else None


def decode_signals(dbc, frame) -> tuple[str, dict] | None:
    """(message name, numeric signals) of a frame the DBC describes, else None."""
    message = message_of(dbc, frame)
    if message is None:
        return None
    try:
        decoded = message.decode(frame.data, decode_choices=False)
    except Exception:  # a frame the DBC does not describe correctly is still recorded raw
        return None
    return message.name, {k: float(v) for k, v in decoded.items() if isinstance(v, int | float)}


def name_problem(signal, value: str, in_yaml: bool = True) -> str | None:
    """Why text cannot be the signal's value (None if it is a name of its value table, even one that
    looks like a number): a number YAML read as text (in_yaml: '12' quoted, 1e3), else a name the
    value table lacks."""
    from .scenario import text_number
    names = [str(v) for v in (signal.choices or {}).values()]
    if value in names:
        return None
    form = text_number(value) if in_yaml else None
    if form is not None:
        return f"YAML reads {value!r} as text, not a number for {signal.name}: write {form}"
    return (f"{value!r} is not in {signal.name}'s value table {names}" if names
            else f"{signal.name} has no value table: give a number")


def value_range(signal) -> tuple[float, float, str]:
    """(lowest, highest, where from) of the physical values a signal can carry: what its raw bits
    encode at its scale and offset, narrowed to the DBC's minimum and maximum where it gives them
    (cantools reads [0|0] as none); where from is empty when the DBC's limits are the range."""
    lo, hi, encoded = -math.inf, math.inf, ""
    if not signal.is_float:  # a float signal's bits carry any value a scenario would give
        raw = (-(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1) if signal.is_signed \
            else (0, 2 ** signal.length - 1)
        ends = sorted(r * signal.scale + signal.offset for r in raw)
        lo, hi = ends
        encoded = (f"what its {signal.length}{' signed' if signal.is_signed else ''} bits at scale "
                   f"{signal.scale:g}, offset {signal.offset:g} carry: [{lo:g}, {hi:g}]")
    dbc_lo, dbc_hi = signal.minimum, signal.maximum
    inside = dbc_lo is not None and dbc_hi is not None and lo <= dbc_lo and dbc_hi <= hi
    if dbc_lo is not None:
        lo = max(lo, dbc_lo)
    if dbc_hi is not None:
        hi = min(hi, dbc_hi)
    if inside or not encoded:
        return lo, hi, ""
    given = "" if dbc_lo is None and dbc_hi is None else \
        f"the DBC's [{'' if dbc_lo is None else f'{dbc_lo:g}'}|{'' if dbc_hi is None else f'{dbc_hi:g}'}] and "
    return lo, hi, given + encoded


def range_problem(signal, value: float) -> str | None:
    """Why a number is not one of the signal's physical values (None if it is one)."""
    lo, hi, where = value_range(signal)
    slack = 1e-9 * max(1.0, abs(lo) if math.isfinite(lo) else 0.0, abs(hi) if math.isfinite(hi) else 0.0)
    if lo - slack <= value <= hi + slack:  # the ends as scale * raw + offset computes them
        return None
    return (f"{value:g} is outside {signal.name}'s range [{lo:g}, {hi:g}]{' ' + signal.unit if signal.unit else ''}"
            + (f" ({where})" if where else ""))


def cycle_time_ms(message) -> float | None:
    """The message's GenMsgCycleTime (ms) when the DBC gives one above 0 and its send type
    (GenMsgSendType, where the DBC has it) is a cyclic one; else None (event-driven, unknown)."""
    if not message.cycle_time or message.cycle_time <= 0:
        return None
    send_type = message.send_type
    if send_type is not None and "cyclic" not in str(send_type).lower():
        return None
    return float(message.cycle_time)
