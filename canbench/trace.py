"""CAN traces and the candump -L codec: the one parser (parse_line, iter_candump) and
formatter (format_line) of the format, used for traces, the bus capture (can.log), the
send logs and the benchmarks. Stamps stay integer nanoseconds (python-can's reader makes
them floats, 0.2 us apart at today's epoch). Other formats (.asc .blf .csv .trc .mf4) are
read with python-can's readers, text ones with the line each frame came from; every format
passes the same checks (iter_trace): CAN 2.0 data and remote frames only (a CAN FD or error
frame is refused, never truncated or replayed as data), ids in range, time never going back."""
from __future__ import annotations

import base64
import binascii
import logging
import re
import string
import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import can

from .blf import BLFReader
from .errors import NotClassicFrame, TraceError
from .files import file_problem
from .trace_frames import TraceFrames
from .wire import EXT_ID_MAX, STD_ID_MAX, Frame

# candump -L grammar (can-utils lib.h), e.g. "(1700000000.123456) vcan0 123#DEADBEEF":
#   (<sec>.<usec|nsec>) <iface> <id>#<data>     id: 3 hex = 11-bit, 8 hex = 29-bit
#   <id>#R[<dlc>]  remote frame          <id>##<flags><data>  CAN FD
CANDUMP_LINE = re.compile(
    r"^\((?P<sec>\d+)\.(?P<frac>\d{1,9})\)\s+(?P<iface>[A-Za-z0-9_.-]+)\s+"
    r"(?P<id>[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#(?P<body>(?:R[0-9]?|#[0-9A-Fa-f][0-9A-Fa-f]*|(?:[0-9A-Fa-f]{2})*))"
    r"(?:\s+[TR])?\s*$")
# the same frame grammar without the timestamp, as the send logs write it: "vcan0 123#DEAD"
FRAME_TEXT = re.compile(CANDUMP_LINE.pattern.replace(r"^\((?P<sec>\d+)\.(?P<frac>\d{1,9})\)\s+", "^"))
# candump -d, when the kernel dropped frames for its socket (written where the frames are missing)
DROPCOUNT = re.compile(r"^DROPCOUNT: dropped (\d+) CAN frames? on '([^']*)' socket \(total drops (\d+)\)")
CAN_ERR_FLAG = 0x20000000
MAX_TRACE_FRAMES = 10_000_000
CANDUMP_SUFFIXES = (".log", ".candump", "")
TEXT_READERS = {".asc": can.ASCReader, ".trc": can.TRCReader, ".csv": can.CSVReader}  # line = the file's line
BINARY_SUFFIXES = (".blf", ".mf4")  # python-can's LogReader; "line" = the frame's number
FORMATS_SAID = "candump -L (.log, .candump or no suffix), or .asc .blf .csv .trc (python-can; .mf4 with asammdf)"
FRAME_CACHE = 1 << 20  # distinct frame texts kept for sharing (then it starts again: only memory is at stake)
STREAM_CACHE = 1 << 14  # the same for a pass that keeps no frames (summarise, validate): ~4 MiB
MAX_STAMP_S = float(1 << 33)  # ~2242: python-can's stamps are s since 1970; beyond, a damaged field


ERROR_FRAME = ("an error frame: the bridge carries CAN 2.0 data and remote frames only (remove error frames: "
               "canbench scaffold leaves them out of the trace it writes)")


ERROR_KIND, FD_KIND = "error frame", "CAN FD frame"  # NotClassicFrame's kinds, as summaries count them


class NotClassic(ValueError):
    """A python-can message that is a whole frame a CAN 2.0 replay cannot send, of a kind."""

    def __init__(self, message: str, kind: str):
        super().__init__(message)
        self.kind = kind


FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)  # the data lengths a CAN FD frame can have


def fd_refusal(size: int, brs: bool, esi: bool) -> str:
    """Why a CAN FD frame is refused: the bridge, its wire format and the bus are CAN 2.0."""
    flags = "".join(f", {name}" for name, on in (("BRS", brs), ("ESI", esi)) if on)
    return (f"a CAN FD frame ({size} data bytes{flags}): the bridge carries CAN 2.0 frames only "
            "(remove FD frames from the trace: canbench scaffold leaves them out of the trace it writes)")


def _frame(m: re.Match, path: str, lineno: int | None) -> Frame:
    ident, body = m["id"], m["body"]
    can_id = int(ident, 16)
    extended = len(ident) == 8
    if not extended and can_id > STD_ID_MAX:
        raise TraceError(path, lineno, f"11-bit id {ident} is above 7FF")
    if extended and can_id > EXT_ID_MAX:
        if can_id & CAN_ERR_FLAG and not body.startswith(("#", "R")) and len(body) <= 16:
            raise NotClassicFrame(path, lineno, ERROR_FRAME, ERROR_KIND)  # the kernel's: 8 data bytes at most
        raise TraceError(path, lineno, f"29-bit id {ident} is above 1FFFFFFF: the bridge carries CAN 2.0 data "
                         "and remote frames only")
    if body.startswith("#"):  # "##<flags nibble><data>": flags 1 BRS, 2 ESI
        digits = body[2:]
        if len(digits) % 2 or len(digits) // 2 not in FD_LENGTHS:
            raise TraceError(path, lineno, f"'##{body[1:]}': not a CAN FD frame (an even number of hex digits, "
                             f"{', '.join(map(str, FD_LENGTHS))} bytes)")
        flags = int(body[1], 16)
        raise NotClassicFrame(path, lineno, fd_refusal(len(digits) // 2, bool(flags & 1), bool(flags & 2)), FD_KIND)
    if body.startswith("R"):
        if int(body[1:] or 0) > 8:
            raise TraceError(path, lineno, f"remote frame dlc {body[1:]}: classic CAN's is 0..8")
        return Frame(can_id, int(body[1:] or 0), b"", extended, True)
    if len(body) > 16:
        raise TraceError(path, lineno, f"{len(body) // 2} data bytes: classic CAN carries at most 8")
    data = bytes.fromhex(body)
    return Frame(can_id, len(data), data, extended)


# candump's own formats without -L: '  can0  123   [4]  DE AD BE EF', with -ta/-td/-tz/-tA a stamp first
CANDUMP_DEFAULT = re.compile(r"^\s*(\([^)]*\)\s+)?[A-Za-z0-9_.-]+\s+[0-9A-Fa-f]{3,8}\s+\[\d+\]")


# candump -8 (len8_dlc): 8 data bytes with the raw DLC code 9..F that carried them, '123#...._9'
CANDUMP_LEN8_DLC = re.compile(r"#[0-9A-Fa-f]{16}_[9A-Fa-f]\s*$")


def not_candump_l(line: str) -> str:
    """Why a line is no candump -L frame, saying so when it is candump's other output."""
    hint = (" (candump's default output: record with candump -L, the log format canplayer reads)"
            if CANDUMP_DEFAULT.match(line) else
            " (candump -8's raw DLC code 9..F for 8 bytes: the bench sends classic frames of DLC 0..8; "
            "record without -8, or drop the '_<code>')" if CANDUMP_LEN8_DLC.search(line) else "")
    return f"not a candump -L frame: {line.strip()[:80]!r}{hint}"


def parse_line(line: str, path: str = "<candump>", lineno: int | None = None,
               cache: dict[tuple[str, str], Frame] | None = None) -> tuple[int, str, Frame] | None:
    """(timestamp ns since the epoch, interface, frame) of one candump -L line; None for lines
    canplayer skips (not starting with '('; candump -d's DROPCOUNT lines). The fraction is
    microseconds (candump -L) or nanoseconds, taken exactly: no float on the way.
    cache: frames already parsed, by their text (one object per content: traffic repeats)."""
    if not line.startswith("("):
        return None
    m = CANDUMP_LINE.match(line)
    if not m:
        raise TraceError(path, lineno, not_candump_l(line))
    t_ns = int(m["sec"]) * 1_000_000_000 + int(m["frac"].ljust(9, "0"))
    if cache is None:
        return t_ns, m["iface"], _frame(m, path, lineno)
    text = (m["id"], m["body"])
    frame = cache.get(text)
    if frame is None:
        if len(cache) > FRAME_CACHE:
            cache.clear()
        frame = cache[text] = _frame(m, path, lineno)
    return t_ns, m["iface"], frame


def parse_frame_text(text: str, path: str = "<frame>", lineno: int | None = None) -> tuple[str, Frame]:
    """(interface, frame) of candump's frame part, 'vcan0 123#DEAD' (Frame.candump's output)."""
    m = FRAME_TEXT.match(text)
    if not m:
        raise TraceError(path, lineno, f"not a frame in candump form: {text[:80]!r}")
    return m["iface"], _frame(m, path, lineno)


def format_line(t_ns: int, iface: str, frame: Frame) -> str:
    """One candump -L line (microsecond stamp, as candump writes it), without the newline."""
    sec, ns = divmod(t_ns, 1_000_000_000)
    return f"({sec}.{ns // 1000:06d}) {frame.candump(iface)}"


def iter_candump(path: str | Path, interface: str | None = None, drops: dict[str, int] | None = None,
                 growing: bool = False, cache_size: int = FRAME_CACHE, strict: bool = False,
                 on_error: Callable[[TraceError], None] | None = None) -> Iterator[tuple[int, int, str, Frame]]:
    """(line number, t_ns, interface, frame) of every frame line of a candump -L file.
    drops: filled with the frames candump says the kernel dropped, per interface (DROPCOUNT).
    growing: candump may still be writing, so a last line without its newline is skipped.
    cache_size: distinct frame texts kept for sharing (a reader in bounded memory keeps fewer).
    strict: a trace someone wrote: a line that is not a frame, blank, a '#' comment or DROPCOUNT
    is an error (not skipped as canplayer would: it may be a frame a tool mangled).
    on_error: a bad line is handed to it and the scan goes on (else it raises TraceError).
    A UTF-8 byte order mark (an editor's) is not part of the first line."""
    cache: dict[tuple[str, str], Frame] = {}
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for lineno, raw in enumerate(f, 1):
            if growing and not raw.endswith("\n"):
                return
            if len(cache) > cache_size:
                cache.clear()
            try:
                parsed = parse_line(raw.lstrip(), str(path), lineno, cache)
                if parsed is None and strict and not DROPCOUNT.match(raw) and raw.strip() \
                        and not raw.lstrip().startswith("#"):
                    raise TraceError(str(path), lineno, not_candump_l(raw))
            except TraceError as error:
                problem = error if raw.endswith(("\n", "\r")) else TraceError(  # the last line, unended: a cut,
                    str(path), lineno,                                              # as the other text formats say
                    f"the file ends inside this line: a recording cut there ({raw.strip()[:60]!r})")
                if on_error is None:
                    raise problem from None
                on_error(problem)
                continue
            if parsed is None:
                if drops is not None and (m := DROPCOUNT.match(raw)):
                    drops[m[2]] = drops.get(m[2], 0) + int(m[1])
            elif interface is None or parsed[1] == interface:
                yield (lineno, *parsed)


class _LineCounter:
    """A text file as python-can's text readers take it, counting the lines they read: a frame
    they yield came from the line read last (each reads one frame per line)."""

    def __init__(self, f):
        self.f, self.line, self.text = f, 0, ""
        # (line, problem, kind) of lines python-can would misread or pass over without a word,
        # found here on the way to it; refused: the last such line (a frame read from it is dropped)
        self.problems: list[tuple[int, str, str | None]] = []
        self.refused = 0

    def __iter__(self):
        return self

    def __next__(self) -> str:
        self.text = next(self.f)
        self.line += 1
        return self.text

    def close(self) -> None:
        self.f.close()

    def said(self, fail: Callable[..., None]) -> None:
        """Each problem found since, to fail."""
        for line, problem, kind in self.problems:
            fail(line, problem, kind)
        self.problems.clear()


class _AscLines(_LineCounter):
    """An ASC file as python-can's ASCReader takes it. Its header reader stops at the first line
    that is not a date, base, comment or 'internal events logged' line and drops that line: in a
    file without the events line, the first frame. That line is given here when missing (not
    counted: lines stay the file's). Blank lines in the header are passed over (at one the reader
    stopped, and read a 'base dec' after it as hex). 'timestamps relative' is refused at its line:
    the reader takes every stamp as absolute."""

    def __init__(self, f, path: Path):
        super().__init__(f)
        self.path, self.header = path, True
        self.pending: str | None = None

    def __next__(self) -> str:
        if self.pending is not None:
            self.line, self.text, self.pending = self.line + 1, self.pending, None
            return self.text
        text = super().__next__()
        if not self.header:
            if (problem := _asc_line_problem(text)) is not None:
                self.problems.append((self.line, problem, None))
                self.refused = self.line
            return text
        while not text.strip():  # python-can's header reader stops at a blank line: a base line after it went unread
            text = super().__next__()
        line = text.strip()
        if ASC_RELATIVE.match(line):
            raise TraceError(str(self.path), self.line, "timestamps relative: the bench reads absolute ASC stamps "
                             "(python-can takes each as absolute); export the log with absolute timestamps")
        if ASC_EVENTS.match(line):
            self.header = False
        elif not ASC_HEADER.match(line):
            self.header, self.pending, self.line = False, text, self.line - 1
            return "no internal events logged\n"
        return text


class _TrcLines(_LineCounter):
    """A TRC file as python-can's TRCReader takes it, but for TRC 1.0's error frames ('2) 1842
    0008 4 ERROR 00 19 08 08', PEAK's format description): its reader stops at the whole file on
    one (it reads 'ERROR' as a data byte), so each is passed over here and said as an error frame."""

    def __init__(self, f, version: str | None):
        super().__init__(f)
        self.v1_0 = version in (None, "1.0")

    def __next__(self) -> str:
        text = super().__next__()
        while self.v1_0 and TRC_1_0_ERROR.match(text):
            self.problems.append((self.line, ERROR_FRAME, ERROR_KIND))
            text = super().__next__()
        return text


TRC_1_0_ERROR = re.compile(r"^\s*\d+\)\s+\S+\s+[0-9A-Fa-f]+\s+\d+\s+ERROR\b")
# TRC 1.x's data bytes end the line, two hex digits each (2.x's columns python-can checks itself)
TRC_1_X_BYTES = re.compile(r"(?:\s+[0-9A-Fa-f]{2})+\s*$")
# an ASC classic frame line, Vector's grammar: <time> <ch> <id>[x] <Rx|Tx> <d|r> <dlc> <data bytes> ...
ASC_CLASSIC_LIKE = re.compile(r"^\s*(?P<time>\d+[.,]\d+)\s+\d+\s+[0-9A-Fa-f]{1,8}x?\s+(?P<f1>\S+)(?:\s+(?P<f2>\S+))?")
ASC_DIRECTIONS = ("rx", "tx", "txrq")


def _asc_line_problem(text: str) -> str | None:
    """Why an ASC line shaped like a classic frame is none python-can reads right: its reader passes
    over a frame line without a direction, with another word there or a decimal comma in the stamp,
    and reads any type but 'r' as data. None: not such a line, or a good one."""
    m = ASC_CLASSIC_LIKE.match(text)
    if not m:
        return None
    f1, f2 = m["f1"].lower(), (m["f2"] or "").lower()
    if f1 in ("d", "r"):
        return f"a frame line without its direction (Rx or Tx) before '{m['f1']}': {text.strip()[:60]!r}"
    if f1 not in ASC_DIRECTIONS and f2 in ("d", "r"):
        return f"direction '{m['f1']}' is not Rx or Tx: {text.strip()[:60]!r}"
    if f1 not in ASC_DIRECTIONS:
        return None  # not a frame line (an event's)
    if "," in m["time"]:
        return f"a decimal comma in the stamp {m['time']!r}: ASC stamps are seconds with a point"
    if f2 not in ("d", "r"):
        return f"frame type '{m['f2'] or ''}' is not d (data) or r (remote): {text.strip()[:60]!r}"
    return None


def _extra_bytes(suffix: str, text: str, msg: can.Message, base: str) -> str | None:
    """Why a data frame's line holds more bytes than its DLC (ASC's classic lines, TRC 1.x), which
    python-can reads without a word to the DLC's count: which of the two is wrong no one can tell."""
    if msg.is_remote_frame or msg.is_fd or msg.dlc > 8:
        return None
    if suffix == ".asc":
        tokens = text.split()
        if len(tokens) < 6 or not tokens[1].isdigit() or tokens[4].lower() != "d":  # not a classic data line
            return None
        byte = r"\d{1,3}" if base == "dec" else r"[0-9A-Fa-f]{1,2}"
        count = next((n for n, field in enumerate(tokens[6:]) if not re.fullmatch(byte, field)), len(tokens[6:]))
    else:
        m = TRC_1_X_BYTES.search(text)
        count = len(m[0].split()) if m else 0
    return f"dlc {msg.dlc} with {count} data bytes" if count > msg.dlc else None


ASC_HEADER = re.compile(r"^(date\s|base\s|//)", re.IGNORECASE)  # what ASCReader's header reader reads on past
ASC_EVENTS = re.compile(r"^(no)?\s*internal\s+events\s+logged", re.IGNORECASE)
ASC_RELATIVE = re.compile(r"^base\s+(hex|dec)\s+timestamps\s+relative", re.IGNORECASE)
# a transmit request, not a frame on the bus (python-can's message pattern reads its 'Tx' as one)
ASC_TX_REQUEST = re.compile(r"^\s*\d+\.\d+\s+\d+\s+\S+\s+(\S+\s+)?TxRq\b")
CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"  # python-can's CSVWriter's first line
ENDS = {".asc": ("end triggerblock",), ".trc": (";",), ".csv": ()}  # a last line that is no frame
FRAME_START = {".asc": re.compile(r"^\d+\.\d+\s+\d+\s+\S"), ".trc": re.compile(r"^\d+\)?\s+\d"),
               ".csv": re.compile(r".")}  # a line python-can would read a frame from


def _cut(text: str, msg: can.Message | None, suffix: str, hex_bytes: bool = True) -> bool:
    """Whether an unended last line is a cut one: a frame line python-can read nothing from, a
    data frame with fewer bytes than its dlc, or one whose last byte is half of one (python-can
    reads 'F' as 0F; hex_bytes: the format writes every byte as two digits, not ASC's base dec;
    a line ending in fields of another kind, such as ASC's 'ID = 5', is not judged by its end)."""
    if msg is None:
        return bool(FRAME_START[suffix].match(text))
    if msg.is_remote_frame or not msg.data:
        return False
    if len(msg.data) < msg.dlc:
        return True
    tokens = text.split()
    last = tokens[-1] if tokens else ""
    if not hex_bytes or suffix == ".csv" or "=" in tokens or len(last) != 1 or last not in string.hexdigits:
        return False
    return int(last, 16) == msg.data[-1]  # the line's last field is its last byte, one digit of two


def _unended_line(path: Path) -> tuple[int, str] | None:
    """(line, text) of a text trace's last line when the file has no end of line after it and it
    is not the format's closing line: whole, or a recording cut there (_cut says which)."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        f.seek(max(0, size - 4096))
        tail = f.read()
        if tail.endswith((b"\n", b"\r")):  # lines end as Python's readers split them: LF, CRLF or CR alone
            return None
        text = re.split(rb"\r\n|\r|\n", tail)[-1].decode("utf-8", "replace").strip()
        ends = ENDS.get(path.suffix.lower(), ())
        if not text or (ends and text.lower().startswith(ends)):
            return None
        f.seek(0)
        lines, after_cr = 1, False
        for block in iter(lambda: f.read(1 << 20), b""):
            lines += (block.count(b"\n") + block.count(b"\r") - block.count(b"\r\n")
                      - (after_cr and block.startswith(b"\n")))  # a CRLF across two blocks
            after_cr = block.endswith(b"\r")
    return lines, text


ASC_FD_FRAME = 0x1000  # the flags' EDL bit: the frame was CAN FD (Vector's ASC; python-can's ASCWriter sets it)
ASC_REMOTE = 0x10  # the flags' RTR bit (can-utils' asc2log: ASC_F_RTR)


def _classic_in_fd_line(text: str, msg: can.Message, base: str) -> can.Message:
    """A frame of an ASC `CANFD` line whose flags say it was a classic CAN frame (EDL clear, no BRS
    or ESI, at most 8 bytes), as CANoe logs on a CAN FD channel and can-utils' log2asc -f writes:
    the classic frame (python-can reads every CANFD line as CAN FD), remote by the flags' RTR bit
    (python-can takes every line without data for a remote frame), with the line's DLC code, so
    that a code that is not the data's length is refused as on a classic line. Else the message
    unchanged. Grammar: <time> CANFD <ch> <dir> <id> [<name>] <brs> <esi> <dlc> <length> <data
    bytes> <duration> <bits> <flags> <crc> ..., e.g. '0.010000 CANFD 1 Rx 123 0 0 8 8 01 .. 08 130000 130 0 0'."""
    tokens = text.split()
    at = 5 if len(tokens) > 5 and tokens[5].isdigit() else 6  # an optional symbolic name
    try:
        brs, esi, length = tokens[at], tokens[at + 1], int(tokens[at + 3])
        code = int(tokens[at + 2], 10 if base == "dec" else 16)
        flags = int(tokens[at + 4 + length + 2], 16)
    except (IndexError, ValueError):
        return msg  # not the grammar above: left as python-can read it (refused as CAN FD)
    if flags & ASC_FD_FRAME or brs != "0" or esi != "0" or length > 8:
        return msg
    if flags & ASC_REMOTE:
        return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                           is_extended_id=msg.is_extended_id, is_remote_frame=True, dlc=code,
                           channel=msg.channel, is_rx=msg.is_rx)
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                       dlc=code, data=msg.data[:length], channel=msg.channel, is_rx=msg.is_rx)


def _asc_dlc_code(text: str, msg: can.Message, base: str) -> can.Message:
    """A classic ASC line's frame with the DLC code 9..F the line has and 8 data bytes ('d D 55 AA ..',
    CANalyzer's record of a raw DLC above 8): the frame with that dlc, not CAN FD's length for the code
    that python-can reads (D as 32). Grammar: <time> <ch> <id> <dir> d <dlc> <data bytes> ... Else unchanged."""
    tokens = text.split()
    try:
        code = int(tokens[5], 10 if base == "dec" else 16)
    except (IndexError, ValueError):
        return msg
    data = tokens[6:6 + 9]
    length = next((n for n, byte in enumerate(data) if not re.fullmatch(r"[0-9A-Fa-f]{1,3}", byte)), len(data))
    if tokens[4].lower() != "d" or not 8 < code <= 15 or length != 8:
        return msg
    return can.Message(timestamp=msg.timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                       dlc=code, data=msg.data, channel=msg.channel, is_rx=msg.is_rx)


def _csv_problem(text: str) -> str | None:
    """Why a python-can CSV row's flags are not its 0/1 (it reads 'true' as 0: a 29-bit frame as 11-bit),
    or its data is no base64 (its reader drops the characters that are none and reads the rest)."""
    fields = text.strip().split(",")
    if len(fields) >= 5 and any(flag not in ("0", "1") for flag in fields[2:5]):
        return f"extended, remote and error are 0 or 1 in python-can's CSV, not {','.join(fields[2:5])!r}"
    if len(fields) >= 7:
        try:
            base64.b64decode(fields[6], validate=True)
        except binascii.Error:
            return f"data {fields[6][:40]!r} is not base64 (python-can's CSV writes the bytes so)"
    return None


@contextmanager
def _listening(logger: str, handler: logging.Handler, level: int) -> Iterator[None]:
    """handler gets what a python-can reader logs at `level` and above while the block runs (what
    its readers skip with only a log line); the logger's level as it was after."""
    log = logging.getLogger(logger)
    before = log.level
    log.addHandler(handler)
    log.setLevel(level)
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.setLevel(before)


class _ReaderLog(logging.Handler):
    """What python-can's TRC reader only logs, with the line it was reading: a line it could not
    parse (WARNING) and the record types it does not read (INFO 'Unsupported type')."""

    def __init__(self, counter: _LineCounter):
        super().__init__(logging.INFO)
        self.counter = counter
        self.records: list[tuple[int, str, logging.LogRecord]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((self.counter.line, self.counter.text.strip()[:80], record))


# PCAN's TRC record types that are not frames (status, error counters, events, 1.x warnings):
# skipped; an error frame ('ER', 1.x 'Error') is refused; any other type is not a TRC line.
TRC_NOT_FRAMES = {"ST", "EC", "EV", "Warng"}
TRC_ERROR_FRAMES = {"ER", "Error"}
UNSUPPORTED_TYPE = re.compile(r"^TRCReader: Unsupported type '(.*)'$")


def _python_can_messages(path: Path, fail: Callable[..., None]) -> Iterator[tuple[int, can.Message]]:
    """(line, message) of a trace python-can reads: text formats with the file's line, binary ones
    with the frame's number; what its readers skip with only a log line is a problem here."""
    suffix = path.suffix.lower()
    version = _trc_version(path) if suffix == ".trc" else None
    hint = " (the file has no ;$FILEVERSION line: read as TRC 1.0)" if suffix == ".trc" and version is None else ""
    if suffix in TEXT_READERS:
        unended = _unended_line(path)
        cut_said = f"the file ends inside this line: a recording cut there ({unended[1][:60]!r})" if unended else ""
        if suffix == ".csv":
            with open(path, encoding="utf-8-sig", errors="replace") as f:
                first = f.readline().strip()
            if first != CSV_HEADER:
                raise TraceError(str(path), 1, f"python-can's CSV begins with the line {CSV_HEADER} "
                                 f"(its reader skips the first line whatever it is): {first[:60]!r}")
        f = open(path, encoding="utf-8-sig", errors="replace")
        counter: _LineCounter = (_AscLines(f, path) if suffix == ".asc" else
                                 _TrcLines(f, version) if suffix == ".trc" else _LineCounter(f))
        log = _ReaderLog(counter)
        try:
            with _listening("can.io.trc", log, logging.INFO):
                reader = TEXT_READERS[suffix](counter)
                for msg in reader:
                    line = counter.line
                    base = str(getattr(reader, "base", "hex")).lower()  # ASC: as its header said (read by now)
                    _reader_problems(log, fail)
                    counter.said(fail)
                    if line == counter.refused:
                        continue
                    if unended and line == unended[0]:
                        cut = _cut(unended[1], msg, suffix, base != "dec")
                        unended = None  # judged once
                        if cut:
                            fail(line, cut_said)
                            continue
                    if suffix == ".asc" and ASC_TX_REQUEST.match(counter.text):
                        continue  # a transmit request is no frame on the bus
                    if suffix == ".asc" and msg.is_fd and not msg.is_error_frame:
                        msg = _classic_in_fd_line(counter.text, msg, base)
                    elif suffix == ".asc" and msg.dlc > 8 and not msg.is_remote_frame:
                        msg = _asc_dlc_code(counter.text, msg, base)
                    problem = _csv_problem(counter.text) if suffix == ".csv" else None
                    if suffix == ".asc" or (suffix == ".trc" and (version or "1.0").startswith("1.")):
                        problem = _extra_bytes(suffix, counter.text, msg, base)
                    if problem:
                        fail(line, problem)
                        continue
                    yield line, msg
                _reader_problems(log, fail)
                counter.said(fail)
                if unended and _cut(unended[1], None, suffix):  # python-can read nothing from it
                    fail(unended[0], cut_said)
        except TraceError:
            raise
        except Exception as e:  # noqa: BLE001 - python-can raises many kinds for bad lines
            if unended and counter.line == unended[0]:  # what it could not read is a cut last line
                raise TraceError(str(path), counter.line, cut_said) from None
            raise TraceError(str(path), counter.line or None, f"python-can cannot read it: {e}{hint}") from None
        finally:
            counter.close()
        return
    if suffix == ".gz":
        raise TraceError(str(path), None, f"a compressed trace: decompress it (gunzip {path.name}) so that "
                         "every check of its format reads it")
    if suffix not in BINARY_SUFFIXES:
        hint = ""
        try:
            with open(path, encoding="utf-8-sig", errors="replace") as f:
                first = next((text for text in f if text.strip() and not text.startswith("#")), "")
            if CANDUMP_LINE.match(first.lstrip()):
                hint = f": its lines read as candump -L, rename it {path.stem}.log"
        except OSError:
            pass
        raise TraceError(str(path), None, f"unknown trace format '{path.suffix}'{hint} (the bench reads "
                         f"{FORMATS_SAID})")
    try:
        reader = BLFReader(str(path)) if suffix == ".blf" else can.LogReader(str(path))  # BLF: CAN_ERROR objects too
        recorded = getattr(reader, "file_size", 0) if suffix == ".blf" else 0
        if recorded > path.stat().st_size:  # python-can reads a cut BLF to its cut, silently
            fail(None, f"truncated: its header says {recorded} bytes, the file has {path.stat().st_size} "
                       "(a recording cut short, or an incomplete copy)")
        elif suffix == ".blf" and recorded != path.stat().st_size and (cut_at := _blf_cut_at(path)) is not None:
            unfinished = recorded <= 144  # the sizes a logger writes at the start (python-can: 144), never updated
            fail(None, f"truncated: its last object (at byte {cut_at}) ends past the file's end" + (
                ", and its header was never finished (a logger stopped without closing the file, or an incomplete "
                "copy)" if unfinished else ""))
        skipped = _Skipped()
        with _listening("can.io.blf", skipped, logging.WARNING):  # what it skips with only a warning
            for number, msg in enumerate(reader, 1):
                skipped.said(fail, number)
                yield number, msg
            skipped.said(fail, None)
    except TraceError:
        raise
    except Exception as e:  # noqa: BLE001 - python-can raises many kinds for bad files
        reason = str(e) or f"{type(e).__name__}, bytes it reads as no object: a damaged file?"
        raise TraceError(str(path), None, f"python-can cannot read it: {reason}") from None


class _Skipped(logging.Handler):
    """The warnings of python-can's BLF reader: a container of an unknown compression method or
    an object of an unknown header version is skipped with only a log line, and the frames in it
    would be missing from the replay without a word."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())

    def said(self, fail: Callable[..., None], number: int | None) -> None:
        """Each warning since, as a problem before frame `number` (None: at the file's end)."""
        for message in self.messages:
            where = f"before frame {number}" if number is not None else "after the last frame"
            fail(None, f"python-can skipped part of it {where} ({message}): the frames there are not read")
        self.messages.clear()


def _blf_cut_at(path: Path) -> int | None:
    """Where the BLF object that runs past the file's end begins (None: every object whole). A
    logger that stopped without closing the file leaves its header's sizes unwritten, and
    python-can reads its last object container to the cut without a word."""
    with open(path, "rb") as f:
        head = f.read(8)  # "LOGG", the header's size: the first object follows it
        pos = struct.unpack_from("<L", head, 4)[0] if len(head) == 8 else 0
        size = path.stat().st_size
        while pos + 16 <= size:
            f.seek(pos)
            signature, _, _, obj_size, _ = struct.unpack("<4sHHLL", f.read(16))
            if signature != b"LOBJ" or obj_size < 16:
                return None  # not what python-can reads either: its own error says it
            if pos + obj_size > size:
                return pos
            pos += obj_size + obj_size % 4  # objects are padded as python-can reads them
    return pos if 0 < size - pos < 16 else None


TRC_VERSIONS = ("1.0", "1.1", "1.3", "2.0", "2.1")  # what python-can's TRC reader reads (no FILEVERSION: 1.0)


def _trc_version(path: Path) -> str | None:
    """A TRC file's version (None: its header has none). One python-can does not read is refused
    at its header line (it would read the lines in another version's columns)."""
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for lineno, text in enumerate(f, 1):
            if not text.startswith(";"):
                return None
            if text.startswith(";$FILEVERSION="):
                version = text.strip().split("=", 1)[1]
                if version not in TRC_VERSIONS:
                    raise TraceError(str(path), lineno, f"TRC file version {version}: python-can reads "
                                     f"{', '.join(TRC_VERSIONS)} (PCAN-View saves 2.1)")
                return version
    return None


def _reader_problems(log: _ReaderLog, fail: Callable[..., None]) -> None:
    for line, text, record in log.records:
        unsupported = UNSUPPORTED_TYPE.match(record.getMessage())
        if record.levelno >= logging.WARNING and text:  # not the end of a file without frames
            fail(line, f"python-can cannot read it: {text!r}")
        elif unsupported and unsupported[1] in TRC_ERROR_FRAMES:
            fail(line, ERROR_FRAME, ERROR_KIND)
        elif unsupported and unsupported[1] not in TRC_NOT_FRAMES and not text.lstrip().startswith(";"):
            # a ';' line is a comment: python-can hands back the header's last one at the end of a file
            # without frames
            fail(line, f"not a TRC frame (record type '{unsupported[1]}'): {text!r}")
    log.records.clear()


def _frame_of_message(msg: can.Message) -> Frame:
    """The CAN 2.0 frame of a python-can message, or ValueError saying why it is none."""
    if msg.is_error_frame:
        raise NotClassic(ERROR_FRAME, ERROR_KIND)
    if msg.is_fd or (len(msg.data) > 8 and len(msg.data) in FD_LENGTHS):  # CSV has no FD flag: longer is FD
        raise NotClassic(fd_refusal(len(msg.data), msg.bitrate_switch, msg.error_state_indicator), FD_KIND)
    can_id, extended = msg.arbitration_id, msg.is_extended_id
    if not 0 <= can_id <= (EXT_ID_MAX if extended else STD_ID_MAX):
        raise ValueError(f"{'29' if extended else '11'}-bit id {can_id:X} is above "
                         f"{EXT_ID_MAX if extended else STD_ID_MAX:X}")
    if not msg.is_remote_frame and 8 < msg.dlc <= 15 and len(msg.data) == 8:
        raise ValueError(f"DLC {msg.dlc:X} ({msg.dlc}) with 8 data bytes (a CAN 2.0 frame's DLC 9..F carries 8, "
                         "as a logger records the raw code): the bench sends DLC 0..8; set the frame's DLC to 8")
    if not 0 <= msg.dlc <= 8:
        raise ValueError(f"dlc {msg.dlc}: classic CAN's is 0..8 (a CAN FD frame? the bridge carries CAN 2.0 only)")
    if msg.is_remote_frame:
        return Frame(can_id, msg.dlc, b"", extended, True)
    data = bytes(msg.data)
    if len(data) > 8:
        raise ValueError(f"{len(data)} data bytes: classic CAN carries at most 8")
    if msg.dlc != len(data):
        raise ValueError(f"dlc {msg.dlc} with {len(data)} data bytes")
    return Frame(can_id, len(data), data, extended)


def numbered(path: Path) -> bool:
    """Whether a trace's frames are numbered (binary formats) rather than at lines of the file."""
    return path.suffix.lower() in BINARY_SUFFIXES


def where_in(path: Path, line: int) -> str:
    """'line N' or 'frame N' of a trace, as iter_trace numbers its frames."""
    return f"{'frame' if numbered(path) else 'line'} {line}"


def _stamp_ns(timestamp: float) -> int:
    """A python-can float stamp in integer ns, rounded to the microsecond: at today's epoch a float
    is 0.24 us coarse and python-can's sums (start time + offset) err by as much (a TRC's 10.000 ms
    read as 9.99999); no format it reads resolves a CAN frame finer than that."""
    return round(timestamp * 1e6) * 1000


def iter_trace(path: str | Path, interfaces: set[str] | None = None,
               on_problem: Callable[[TraceError], None] | None = None,
               cache_size: int = FRAME_CACHE,
               drops: dict[str, int] | None = None,
               left_out: dict[str, list[int]] | None = None) -> Iterator[tuple[int, int, str | None, Frame]]:
    """(line, t_ns, interface or None, frame) of every frame of a trace in any format the bench
    reads, checked alike: CAN 2.0 data and remote frames only, ids in range, dlc 0..8, time never
    going back, interfaces among `interfaces` (None: any). line: the file's line (text formats),
    the frame's number (.blf, .mf4: said as 'frame N'). A problem raises TraceError, or with
    on_problem is handed to it and the frame left out (validate: every problem at once).
    cache_size: candump frame texts kept for sharing (STREAM_CACHE: a pass that keeps no frames).
    drops: filled with the frames a candump -d recording says the kernel dropped, per interface.
    left_out: given, an error frame or a CAN FD frame is left out and its line added here under
    its kind (NotClassicFrame.kind), not a problem: what summarise and scaffold do with a recording (a
    scenario's trace has neither)."""
    path = Path(path)
    if (problem := file_problem(path, "trace file", named=False)) is not None:
        raise TraceError(str(path), None, problem)
    if path.stat().st_size == 0:  # in every format (a binary reader would say its header is short)
        return
    if not numbered(path):
        with open(path, "rb") as f:
            if f.read(2) in (b"\xff\xfe", b"\xfe\xff"):  # Windows tools' "Unicode": read as UTF-8, no frame at all
                raise TraceError(str(path), 1, "UTF-16 text: save the trace as UTF-8 (or ASCII)")
    by_number = numbered(path)
    # python-can numbers ASC and BLF channels from 0; the file, CANalyzer and CANoe from 1: said as the file has them
    zero_based = path.suffix.lower() in (".asc", ".blf")

    def fail(line: int | None, message: str, kind: str | None = None) -> None:
        if left_out is not None and kind is not None:
            left_out.setdefault(kind, []).append(line or 0)
            return
        error = (TraceError(str(path), None, f"frame {line}: {message}") if by_number and line
                 else TraceError(str(path), line, message))
        if on_problem is None:
            raise error
        on_problem(error)

    def bad_line(error: TraceError) -> None:  # candump's: raised as they are, error and FD frames counted
        if left_out is not None and isinstance(error, NotClassicFrame):
            left_out.setdefault(error.kind, []).append(error.line or 0)
        elif on_problem is None:
            raise error
        else:
            on_problem(error)

    # time never goes back per interface: candump of several interfaces writes each socket's frames
    # as it reads them (one per wakeup), so its lines are in order per interface only
    last: dict[str | None, tuple[int, int]] = {}  # interface -> (t_ns, line) of its last frame
    said = "frame" if by_number else "line"

    def went_back(line: int, t_ns: int, iface: str | None) -> str | None:
        # each frame against the one before it (not the latest stamp so far): a clock that jumped
        # back once is one problem, not one per frame after it
        before = last.get(iface)
        last[iface] = (t_ns, line)
        if before is None or t_ns >= before[0]:
            return None
        stamps = f" ({t_ns / 1e9:.6f} s after {before[0] / 1e9:.6f} s)"
        if len(last) == 1:
            return f"timestamp earlier than the {said} before{stamps}"
        return f"timestamp earlier than {said} {before[1]}'s, the frame before on {iface}{stamps}"

    if path.suffix.lower() in CANDUMP_SUFFIXES:
        for lineno, t_ns, iface, frame in iter_candump(path, drops=drops, strict=True, on_error=bad_line,
                                                     cache_size=cache_size):
            if interfaces is not None and iface not in interfaces:
                fail(lineno, f"interface '{iface}' is not one of {sorted(interfaces)} (remap it in the scenario)")
                continue
            problem = went_back(lineno, t_ns, iface)
            if problem:
                fail(lineno, problem)
            yield lineno, t_ns, iface, frame
        return
    for line, msg in _python_can_messages(path, fail):
        try:
            frame = _frame_of_message(msg)
        except NotClassic as e:
            fail(line, str(e), e.kind)
            continue
        except ValueError as e:
            fail(line, str(e))
            continue
        channel = (None if msg.channel is None else
                   str(msg.channel + 1 if zero_based and isinstance(msg.channel, int) else msg.channel))
        if interfaces is not None and channel is not None and channel not in interfaces:
            fail(line, f"interface '{channel}' is not one of {sorted(interfaces)} (remap it in the scenario)")
            continue
        if not 0 <= msg.timestamp < MAX_STAMP_S:  # NaN, inf or a sign: a damaged stamp, not a time
            fail(line, f"timestamp {msg.timestamp!r} s is not a time (0 .. {MAX_STAMP_S:.0f} s since 1970)")
            continue
        t_ns = _stamp_ns(msg.timestamp)
        problem = went_back(line, t_ns, channel)
        if problem:
            fail(line, problem)
        yield line, t_ns, channel, frame


def read_trace(path: str | Path, interfaces: set[str] | None = None, only: str | None = None,
               starts: dict[str | None, int] | None = None) -> TraceFrames:
    """All frames of a trace, in order, each with the line it came from (iter_trace's checks).
    interfaces: names the trace may use (None: any). only: the one interface to keep (a bus
    carries one); None: the trace must have one, since merging several would put two buses'
    frames on one, out of time order (candump's lines are in order per interface only). starts:
    filled with each interface's first stamp (ns), the others' too. The frames are held compactly
    (canbench.trace_frames): about 35 bytes each."""
    frames: TraceFrames | None = None
    seen: dict[str | None, int] = {}  # interface -> its first line
    for line, t_ns, iface, frame in iter_trace(path, interfaces, cache_size=STREAM_CACHE):  # stored as columns
        seen.setdefault(iface, line)
        if starts is not None:
            starts.setdefault(iface, t_ns)
        if only is not None and iface != only:
            continue
        if only is None and len(seen) > 1:
            raise TraceError(str(path), line, several_interfaces(seen))
        if frames is None:
            frames = TraceFrames(iface)
        if len(frames) >= MAX_TRACE_FRAMES:
            raise TraceError(str(path), line, too_many_frames())
        frames.append(line, t_ns, frame)
    if only is not None and seen and only not in seen:
        raise TraceError(str(path), None, f"no frames on interface '{only}' ({interfaces_said(seen)})")
    if not frames:
        raise TraceError(str(path), None, "no frames in trace")
    return frames


def read_replay(path: str | Path, only: str | None) -> tuple[TraceFrames, float | None]:
    """What a replay of the trace sends (of one interface, `only`, or of its only one), and the time
    (s) its frames are sent relative to: their own first for a trace's only interface (None); for
    one interface of several, the trace's start, so its first frame 3 s after the trace's is sent
    3 s after the start. The start is the earliest of the interfaces' first frames, as scaffold's
    split_trace takes it: candump's lines are in time order per interface only, so the first line
    need not be the first frame. One pass over the trace."""
    starts: dict[str | None, int] = {}
    frames = read_trace(path, None, only, starts)
    return frames, min(starts.values()) / 1e9 if only is not None else None


def too_many_frames() -> str:
    """The problem of a trace (of the interface replayed) longer than a run reads."""
    return f"more than {MAX_TRACE_FRAMES} frames: split the trace"


def interfaces_said(seen) -> str:
    """A trace's interfaces as a problem names them: 'it has can0, can1', or that it names none."""
    named = sorted(i for i in seen if i is not None)
    return f"it has {', '.join(named)}" if named else "the trace names no interfaces"


def several_interfaces(seen) -> str:
    """The problem of a trace of several interfaces replayed without saying which."""
    names = sorted(i for i in seen if i is not None) + (["lines that name none"] if None in seen else [])
    return (f"frames of {len(seen)} interfaces ({', '.join(names)}) and one bus: say which "
            f"the scenario replays (interface:), or split the trace one bus each (canbench scaffold)")
