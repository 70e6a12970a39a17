"""DBC files (cantools): loading one (cached per file and mtime, so a scenario's buses and its
checks share one database), a frame's signals as numbers (the recording's /signals channels,
the viewer, the signal expectations), a message's database cycle time and send type, and why a
scenario's value cannot be a signal's.

A DBC is read as written (cantools' strict=False) and then held to cantools' strict rules, and
the bench's (_bench_problem), where it is used: a scenario refuses one whose signals overlap or
pass their message's end unless it says `dbc_strict: false`, a command line unless given --dbc-lenient. Such a message
cantools cannot decode whole (its codec needs the bits in one piece), so it is decoded signal by
signal, each from its own bits as the DBC places them (_one_signal_messages), and it is not encoded:
what the bench sends must carry every signal's value, and overlapping signals cannot.

A 29-bit frame of no message's id is a J1939 message's when the DBC marks one message of its
parameter group J1939 (message_of): a truck's network sends a group from any source address."""
from __future__ import annotations

import copy
import logging
import math
import re
import struct
import weakref
from functools import lru_cache
from pathlib import Path
from typing import Any

import cantools
from cantools.database.can import Message

from . import j1939
from .files import file_problem

# per message that strict reading refuses: why (cantools' words, or _bench_problem's), and the one-signal messages it
# is decoded by; filled when the DBC is loaded, so a database in use is never changed
_AS_WRITTEN: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_PARTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_J1939: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # per database, its J1939 messages by group
# a multiplexed message's one-signal messages, made at its first frame of a page the DBC does not list
_MUX_PARTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


# GenMsgSendType defined as a number (some tools do; Vector's DBCs make it an ENUM): cantools refuses
# the whole file ("Expected str, got int: 1", no line). It is read under another name, so the
# message has no send type and its cycle time decides (send_type_cyclic), as for a DBC without one.
_NUMERIC_SEND_TYPE = re.compile(r'^\s*BA_DEF_\s+BO_\s+"GenMsgSendType"\s+(INT|HEX|FLOAT)\b', re.MULTILINE)


@lru_cache(maxsize=16)
def _load(path: str, mtime_ns: int):
    cantools_log = logging.getLogger("cantools")
    level = cantools_log.level
    cantools_log.setLevel(logging.ERROR)  # its warning of an overwritten duplicate: refused below, named
    try:
        try:
            db = cantools.database.load_file(path, encoding=text_encoding(Path(path)), strict=False)
        except Exception as e:  # noqa: BLE001 - re-raised unless it is the one refusal read around
            text = saved_text(Path(path).read_bytes())
            if "Expected str, got int" not in str(e) or not _NUMERIC_SEND_TYPE.search(text):
                raise
            db = cantools.database.load_string(text.replace('"GenMsgSendType"', '"GenMsgSendTypeNumber"'),
                                               "dbc", strict=False)
    finally:
        cantools_log.setLevel(level)
    if not hasattr(db, "messages"):  # cantools reads a CDD by its suffix as a diagnostics database
        raise DbcError("a diagnostics database (services and identifiers), not CAN messages: give a DBC "
                       "(or a KCD, SYM or ARXML file)")
    _refuse_duplicates(db)
    _hold_to_strict(db)
    return db


def text_encoding(path: Path) -> str | None:
    """How to read a database file: UTF-8 (a byte-order mark dropped) when its bytes are UTF-8,
    else None (cantools' default per format: cp1252 for a DBC or SYM). DBCs come in both, and
    cp1252 reads UTF-8's ö as Ã¶ (a value-table name no scenario can write) and its mark as text
    before VERSION that cantools cannot parse; a cp1252 file is almost never valid UTF-8."""
    try:
        path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        return None
    return "utf-8-sig"


def saved_text(data: bytes) -> str:
    """A text file as a tool or spreadsheet saved it, by text_encoding's rule: UTF-8 (its byte-order
    mark dropped) when the bytes are UTF-8, else cp1252 (DBCs, signal-trace CSVs)."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("cp1252", errors="replace")


def _hold_to_strict(db) -> None:
    """Note each message cantools' strict mode, or the bench (_bench_problem), refuses, with why,
    and the parts it is decoded by."""
    for message in db.messages:
        try:
            message.refresh(strict=True)  # raises only once its state is rebuilt as it was
            why = _bench_problem(message)
        except cantools.database.Error as e:
            why = str(e).rstrip(".")
        if why is not None:
            _AS_WRITTEN[message] = why
            _PARTS[message] = _one_signal_messages(message)


def _bench_problem(message) -> str | None:
    """Why a message cantools' strict mode passes cannot be read whole as the DBC writes it: signals
    multiplexed by a signal the DBC does not mark a multiplexer (M; cantools never decodes them, nor
    encodes their values), a float signal of neither 32 nor 64 bits (cantools cannot unpack 8, and
    reads 16 as IEEE half precision, which no DBC type is), a scale of 0 (every frame carries the
    offset: no value can be sent or judged)."""
    by_name = {s.name: s for s in message.signals}
    for signal in message.signals:
        mux = signal.multiplexer_signal
        if mux is not None and not getattr(by_name.get(mux), "is_multiplexer", False):
            return (f"{signal.name} is multiplexed by {mux}, which the DBC does not mark a multiplexer "
                    f"({'M' if mux in by_name else 'no such signal'})")
        if signal.is_float and signal.length not in (32, 64):
            return (f"{signal.name} is a float of {signal.length} bits (a DBC's float is 32 bits, SIG_VALTYPE_ 1, "
                    "or 64, SIG_VALTYPE_ 2)")
        if signal.conversion.scale == 0:
            return f"{signal.name}'s scale is 0 (every frame carries its offset, {signal.conversion.offset:g})"
    return None


def _one_signal_messages(message) -> tuple:
    """A message per signal (with the multiplexers that select it, so a page's signal is read
    only on its pages), each as long as its signal needs: a signal past the DBC's length is read
    from the frames that carry its bytes."""
    by_name = {s.name: s for s in message.signals}
    out = []
    for signal in message.signals:
        chain, at = [signal], signal
        while at.multiplexer_signal in by_name and by_name[at.multiplexer_signal] not in chain:  # a loop ends
            at = by_name[at.multiplexer_signal]
            chain.insert(0, at)
        if signal.is_multiplexer:  # read as a plain signal: its value is one whatever pages the DBC lists
            chain[-1] = copy.copy(signal)
            chain[-1].is_multiplexer = False
        length = max(message.length, *(_end_byte(s) for s in chain))
        out.append(Message(message.frame_id, message.name, length, chain, strict=False,
                           is_extended_frame=message.is_extended_frame))
    return tuple(out)


def _bits(signal) -> set[int]:
    """The frame's bits a signal takes, numbered as in a little-endian start bit (byte * 8 + bit)."""
    if signal.byte_order == "little_endian":
        return set(range(signal.start, signal.start + signal.length))
    out, at = set(), signal.start  # Motorola: from its most significant bit, down each byte, then the next byte
    for _ in range(signal.length):
        out.add(at)
        at = at - 1 if at % 8 else at + 15
    return out


def _end_byte(signal) -> int:
    return max(_bits(signal)) // 8 + 1


def past_can_20(signal) -> str | None:
    """Why no CAN 2.0 frame carries a signal (None if one can): its bits end past the 8th byte,
    as in a DBC read as written whose message is shorter than its signals."""
    end = _end_byte(signal)
    return None if end <= 8 else f"{signal.name}'s bits end in byte {end}: no CAN 2.0 frame (8 bytes) carries it"


def judged_problem(message, signal) -> str | None:
    """Why no frame the bench carries gives a signal's value (None if one can): a message of more
    than 8 bytes (CAN FD: a frame of 8 does not decode as it), bits past the 8th byte, a scale of 0."""
    if too_long_for_can_20(message):
        return (f"{message.name} has {message.length} data bytes (CAN FD): the bench carries CAN 2.0 frames of "
                "at most 8, and no shorter frame decodes as it")
    if why := past_can_20(signal):
        return why
    if signal.conversion.scale == 0:
        return f"{signal.name}'s scale is 0 in the DBC: every frame carries its offset, whatever its bits"
    return None


def as_written_problem(message) -> str | None:
    """Why strict reading refuses a message (None if it does not): signals that overlap or pass its
    end (cantools' strict mode), or what _bench_problem says."""
    return _AS_WRITTEN.get(message)


def strict_problem(db) -> str | None:
    """Why strict reading refuses a DBC (None if it does not): how many messages, the first five named."""
    said = [f"{m.name} ({_AS_WRITTEN[m]})" for m in db.messages if m in _AS_WRITTEN]
    if not said:
        return None
    return (f"{len(said)} message{'s' if len(said) > 1 else ''} it cannot read whole as written (signals that "
            f"overlap or pass the message's end, or below): {'; '.join(said[:5])}{'; ...' if len(said) > 5 else ''}")


def decode(message, data: bytes, scaling: bool = True) -> dict:
    """A frame's signals (numbers, not value-table names), as cantools decodes the message: a
    frame shorter than the message is an error, as for cantools. A multiplexer value the DBC lists
    no page for gives the frame's other signals and the multiplexer (cantools: an error, which
    would lose a page-less signal's value and count its frame as one the DBC does not describe). A
    message strict reading refuses is decoded signal by signal (_one_signal_messages); a signal past
    the DBC's length is left out of a frame too short for it."""
    parts = _PARTS.get(message)
    if parts is None:
        try:
            return message.decode(data, decode_choices=False, scaling=scaling)
        except cantools.database.DecodeError:
            if not message.is_multiplexed() or len(data) < message.length:
                raise
            # a page the DBC does not list (an ECU's reserved one): the signals outside pages and the
            # multiplexers are still the frame's, read signal by signal as below
            parts = _MUX_PARTS.get(message)
            if parts is None:
                parts = _MUX_PARTS[message] = _one_signal_messages(message)
    if len(data) < message.length:
        raise cantools.database.DecodeError(f"wrong data size: {len(data)} instead of {message.length} bytes")
    out: dict = {}
    for part in parts:
        try:
            out.update(part.decode(data, decode_choices=False, scaling=scaling))
        except cantools.database.DecodeError:  # a page its multiplexer does not select, a signal past its bytes
            continue
    return out


def encode_problem(message) -> str | None:
    """Why the bench cannot encode a message (None if it can): signals that overlap or pass its
    end leave no frame that carries each signal's value."""
    why = as_written_problem(message)
    return None if why is None else f"the bench cannot encode {message.name}: {why} in the DBC"


class DbcError(ValueError):
    """A DBC cantools reads but the bench cannot use as it is (the message says what to change)."""


def _refuse_duplicates(db) -> None:
    """Two messages of one id (and format) or one name: cantools keeps the last for lookups, so
    every frame of that id would decode as the last one; two signals of one name in a message:
    a decoded frame holds one value of the name. Refused, naming both."""
    ids: dict[tuple[int, bool], str] = {}
    names: dict[str, int] = {}
    for m in db.messages:
        seen: set[str] = set()
        for signal in m.signals:
            if signal.name in seen:
                raise DbcError(f"message {m.name} has two signals named {signal.name}: give each signal its own name")
            seen.add(signal.name)
        key = (m.frame_id, m.is_extended_frame)
        if key in ids:
            raise DbcError(f"messages {ids[key]} and {m.name} have the same id "
                           f"{m.frame_id:0{8 if m.is_extended_frame else 3}X}: give each message its own id")
        if m.name in names:
            raise DbcError(f"two messages are named {m.name} (ids {names[m.name]:X} and {m.frame_id:X}): "
                           "give each message its own name")
        ids[key], names[m.name] = m.name, m.frame_id


def load_dbc(path: Path | None):
    """The cantools database of a DBC file (None for None); cantools' own error on a bad file,
    DbcError on one it reads but the bench cannot use."""
    return _load(str(path), Path(path).stat().st_mtime_ns) if path else None


def read_dbc(path: Path, lenient: bool = False):
    """load_dbc for a file a user named on the command line: an InputError naming it when it is
    missing or cannot be used, or when strict reading refuses it and lenient is not set
    (--dbc-lenient)."""
    from .errors import InputError
    if (problem := file_problem(Path(path), "DBC file", named=False)) is not None:
        raise InputError(str(path), None, problem)
    try:
        db = load_dbc(path)
    except Exception as e:  # noqa: BLE001 - cantools' parse errors name what it could not read
        raise InputError(str(path), None, load_error_text(e, path=Path(path))) from None
    if not lenient and (why := strict_problem(db)):
        raise InputError(str(path), None, f"strict reading refuses it: {why}; to read it as written, "
                                          "give --dbc-lenient")
    return db


def load_error_text(error: Exception, name: str = "it", path: Path | None = None) -> str:
    """Why a DBC (name) cannot be used, on one line: cantools' message whole (it names what it
    could not read on the lines after its first), or the bench's (DbcError); with the DBC's
    path:line where the message leads to one (_line_of)."""
    said = " ".join(line.strip() for line in str(error).splitlines() if line.strip())[:1000]
    if isinstance(error, DbcError):
        return f"cannot use {name} as a DBC: {said}"
    line = _line_of(path, said) if path is not None else None
    if (big := re.search(r"Standard frame id 0x([0-9a-fA-F]+) is more than 11 bits", said)) is not None:
        said += (f" (a DBC writes a 29-bit id with 0x80000000 added: BO_ {int(big[1], 16) | 0x80000000} for "
                 f"{int(big[1], 16):08X})")
    if "unused VAL_ entries" in said:  # cantools refuses it even reading as written
        said += " (a value table for a signal its message lacks: correct the signal's name, or delete the VAL_)"
    return f"cannot load {name} as a DBC (cantools): " + (f"{path}:{line}: " if line else "") + said


def _line_of(path: Path, said: str) -> int | None:
    """The DBC line a cantools error is about: its `at line N`, else the BO_ of the message it
    names, or the first VAL_ it names (unused: of no signal of that message); None if none."""
    if (at := re.search(r"at line (\d+)", said)) is not None:
        return int(at[1])
    if (m := re.search(r"in message (\w+)", said)) is not None:
        pattern = re.compile(rf"\s*BO_\s+\d+\s+{re.escape(m[1])}\s*:")
    elif (v := re.search(r"VAL_ (\d+) (\w+)", said)) is not None:
        pattern = re.compile(rf"\s*VAL_\s+{v[1]}\s+{re.escape(v[2])}\b")
    else:
        return None
    try:
        text = saved_text(path.read_bytes())
    except OSError:
        return None
    return next((i for i, line in enumerate(text.splitlines(), 1) if pattern.match(line)), None)


def message_of(dbc, frame):
    """The DBC's message of a frame (id and 11/29-bit as the DBC has them), else None: a 29-bit
    frame is looked up among the 29-bit messages whatever its id, as cantools only does for ids
    above 7FF unless told. A 29-bit frame of no message's id is a J1939 message's when the DBC
    marks one of its parameter group (VFrameFormat J1939PG) and only one: the DBC's id names the
    usual sender and priority, and a J1939 network sends a group from any source address, at
    any priority (to any destination, for a PDU1 group). Not the proprietary groups nor UDS,
    whose data each sender defines (j1939.BY_SENDER)."""
    try:
        message = dbc.get_message_by_frame_id(frame.can_id, force_extended_id=frame.extended)
    except KeyError:
        message = None
    if message is not None and message.is_extended_frame == frame.extended:
        return message
    if frame.extended and (groups := _j1939_groups(dbc)) and (pgn := j1939.group_of(frame.can_id)) is not None:
        same = groups.get(pgn, ())
        return same[0] if len(same) == 1 else None  # several senders in the DBC, none this one: whose?
    return None


def group_read(db, message) -> int | None:
    """The J1939 group whose frames from any source are this message's (message_of), else None."""
    pgn = j1939.group_of(message.frame_id) if message.is_extended_frame else None
    return pgn if pgn is not None and _j1939_groups(db).get(pgn) == (message,) else None


def _j1939_groups(db) -> dict[int, tuple]:
    """The DBC's J1939 messages by parameter group number (empty when it marks none J1939)."""
    groups = _J1939.get(db)
    if groups is None:
        found: dict[int, list] = {}
        for m in db.messages:
            if m.protocol == "j1939" and m.is_extended_frame and (pgn := j1939.group_of(m.frame_id)) is not None:
                found.setdefault(pgn, []).append(m)
        groups = _J1939[db] = {pgn: tuple(ms) for pgn, ms in found.items()}
    return groups


def too_long_for_can_20(message) -> bool:
    """A message the bench cannot carry: more than CAN 2.0's 8 data bytes (a CAN FD bus's
    message of up to 8 bytes goes as a CAN 2.0 frame, its bytes as they are)."""
    return message.length > 8


def decode_signals(dbc, frame) -> tuple[str, dict] | None:
    """(message name, numeric signals) of a frame the DBC describes, else None."""
    message = message_of(dbc, frame)
    if message is None:
        return None
    try:
        decoded = decode(message, frame.data)
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


def as_raw(signal, value: float) -> int | float:
    """The raw value a frame carries for a physical value: an integer signal's nearest raw integer
    (exact for 64-bit values: Python ints), a float signal's value at its width (a 32-bit float
    rounded as the frame stores it). Values are compared raw, so a gate is exactly as strict as
    the signal's own resolution."""
    raw = signal.conversion.numeric_scaled_to_raw(value)
    if signal.is_float:
        raw = float(raw)
        if signal.length == 32 and math.isfinite(raw) and abs(raw) <= 3.4028234663852886e38:
            raw = struct.unpack("<f", struct.pack("<f", raw))[0]
    return raw


def raws_of(signal, value) -> tuple[int | float, ...]:
    """Every raw value a scenario's value stands for: a value-table name each raw value the table
    gives that name (tables may name several values alike: 1 'off' 0 'off'), a number its raw."""
    if isinstance(value, str):
        return tuple(raw for raw, name in (signal.choices or {}).items() if str(name) == value)
    return (as_raw(signal, value),)


def grid_problem(signal, value: float) -> str | None:
    """Why a number is between two values an integer signal can carry (None if it is one of them):
    an equality gate on it could never be met. Float signals carry any number (at their width). A
    scale of 0 carries its offset only (and has no raw value for any number: said, not divided by)."""
    if isinstance(value, bool):
        return None
    if signal.conversion.scale == 0:
        return f"{signal.name}'s scale is 0 in the DBC: it carries {signal.conversion.offset:g} only"
    if signal.is_float:
        return None
    raw = as_raw(signal, value)
    carried = signal.conversion.raw_to_scaled(raw, decode_choices=False)
    scale = abs(signal.conversion.scale)
    if carried == value or math.isclose(carried, value, rel_tol=1e-9, abs_tol=scale * 1e-6):
        return None
    toward = 1 if (value > carried) == (signal.conversion.scale > 0) else -1  # a negative scale steps down
    lo, hi = sorted((carried, signal.conversion.raw_to_scaled(raw + toward, decode_choices=False)))
    return (f"{value:.10g} is not a value {signal.name} carries (steps of {signal.conversion.scale:g} from "
            f"{signal.conversion.offset:g}): {lo:.10g} or {hi:.10g}")


def value_range(signal) -> tuple[float, float, str]:
    """(lowest, highest, where from) of the physical values a signal can carry: what its raw bits
    encode at its scale and offset, narrowed to the DBC's minimum and maximum where it gives them
    (cantools reads [0|0] as none); where from is empty when the DBC's limits are the range."""
    lo, hi, encoded = bits_range(signal)
    dbc_lo, dbc_hi = signal.minimum, signal.maximum
    limits = f"the DBC's [{'' if dbc_lo is None else f'{dbc_lo:g}'}|{'' if dbc_hi is None else f'{dbc_hi:g}'}]"
    if dbc_lo is not None and dbc_hi is not None and dbc_lo > dbc_hi:  # a DBC's slip: the bits decide
        return lo, hi, f"{encoded + '; ' if encoded else ''}{limits} is empty, so not used"
    if (dbc_lo is not None and dbc_lo > hi) or (dbc_hi is not None and dbc_hi < lo):
        return lo, hi, f"{encoded}; {limits} is outside it, so not used"
    inside = dbc_lo is not None and dbc_hi is not None and lo <= dbc_lo and dbc_hi <= hi
    if dbc_lo is not None:
        lo = max(lo, dbc_lo)
    if dbc_hi is not None:
        hi = min(hi, dbc_hi)
    if inside or not encoded:
        return lo, hi, ""
    given = "" if dbc_lo is None and dbc_hi is None else f"{limits} and "
    return lo, hi, given + encoded


def bits_range(signal) -> tuple[float, float, str]:
    """(lowest, highest, said) of the physical values a signal's bits encode at its scale and
    offset, whatever the DBC's minimum and maximum say (said: empty for a 64-bit float)."""
    if signal.is_float:  # IEEE 754: a 32-bit float's largest finite value; a 64-bit float's is past any scenario's
        if signal.length != 32:
            return -math.inf, math.inf, ""
        top = FLOAT32_MAX * abs(signal.scale)
        return signal.offset - top, signal.offset + top, f"what a 32-bit float carries: [{-top:g}, {top:g}]"
    raw = (-(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1) if signal.is_signed \
        else (0, 2 ** signal.length - 1)
    lo, hi = sorted(r * signal.scale + signal.offset for r in raw)
    return lo, hi, (f"what its {signal.length}{' signed' if signal.is_signed else ''} bits at scale "
                    f"{signal.scale:g}, offset {signal.offset:g} carry: [{lo:g}, {hi:g}]")


FLOAT32_MAX = 3.4028234663852886e38


def range_problem(signal, value: float) -> str | None:
    """Why a number is not one of the signal's physical values (None if it is one)."""
    lo, hi, where = value_range(signal)
    slack = 1e-9 * max(1.0, abs(lo) if math.isfinite(lo) else 0.0, abs(hi) if math.isfinite(hi) else 0.0)
    if lo - slack <= value <= hi + slack:  # the ends as scale * raw + offset computes them
        return None
    return (f"{value:g} is outside {signal.name}'s range [{lo:g}, {hi:g}]{' ' + signal.unit if signal.unit else ''}"
            + (f" ({where})" if where else ""))


# GenMsgSendType values that say nothing of a cycle: the cycle time decides. Otherwise a type named
# cyclic or periodic (not non-) is cyclic, and any other (Event, OnChange, Triggered, ...) is not
SEND_TYPES_UNSAID = ("", "nomsgsendtype", "notused", "none")


def cycle_time_ms(message) -> float | None:
    """The message's GenMsgCycleTime (ms) when the DBC gives one above 0 and its send type does
    not make it an event message; else None (event-driven, unknown)."""
    cycle = _cycle_number(message)
    if cycle is None or not math.isfinite(cycle) or cycle <= 0:
        return None
    return cycle if send_type_cyclic(message.send_type) else None


def cycle_of_id(dbc, can_id: int, extended: bool) -> tuple[Any, float] | None:
    """(message, its cycle in ms) of frames of this id (message_of: the message of its own id,
    or a J1939 group's from another source) when the DBC gives it a cycle (cycle_time_ms)."""
    from .wire import Frame
    message = message_of(dbc, Frame(can_id, 0, b"", extended))
    cycle = cycle_time_ms(message) if message is not None else None
    return None if cycle is None else (message, cycle)


def _cycle_number(message) -> float | None:
    """GenMsgCycleTime as a number, whatever the attribute's type: an ENUM's value is the index
    of its label (cantools gives the index), a STRING's is its text; None if it is not a number."""
    attribute = message.dbc.attributes.get("GenMsgCycleTime") if message.dbc else None
    cycle = attribute.value if attribute is not None else message.cycle_time  # cantools makes index 0 None
    if attribute is not None and attribute.definition.type_name == "ENUM" and isinstance(cycle, int):
        labels = attribute.definition.choices or []
        cycle = labels[cycle] if 0 <= cycle < len(labels) else None
    if isinstance(cycle, bool) or cycle is None:
        return None
    try:
        return float(cycle)
    except (TypeError, ValueError):
        return None


def send_type_at_most(send_type) -> bool:
    """Whether a cyclic GenMsgSendType also sends on events (EventPeriodic, CyclicAndSpontan,
    CyclicIfActiveAndSpontan, ...): its cycle is then the longest a sender waits, not its rhythm,
    since events come in between."""
    said = _said(send_type)
    return send_type_cyclic(send_type) and any(w in said for w in ("event", "spontan", "onchange", "onwrite"))


def _said(send_type) -> str:
    """A send type as compared: lower case, letters and digits only (Cyclic_If_Active: cyclicifactive)."""
    return "".join(ch for ch in str(send_type or "").lower() if ch.isalnum())


def send_type_cyclic(send_type) -> bool:
    """Whether a GenMsgSendType leaves a message cyclic: Cyclic, CyclicIfActive, FixedPeriodic,
    EventPeriodic, ... are; NonCyclic, Event, OnChange, IfActive, Spontaneous, ... are not; none
    or one that says nothing (NoMsgSendType, NotUsed) leaves it to the cycle time."""
    if send_type is None or isinstance(send_type, int):
        return True
    said = _said(send_type)
    if said in SEND_TYPES_UNSAID:
        return True
    if said.startswith(("non", "no")):
        return False
    return "cyclic" in said or "periodic" in said
