"""CAN traces and the candump -L codec: the one parser (parse_line, iter_candump) and
formatter (format_line) of the format, used for traces, the bus capture (can.log), the
send logs and the benchmarks. Stamps stay integer nanoseconds (python-can's reader makes
them floats, 0.2 us apart at today's epoch). Other formats (.asc .blf .csv .trc .mf4) are
read with python-can's LogReader."""
from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can

from .errors import TraceError
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
FRAME_CACHE = 1 << 20  # distinct frame texts kept for sharing (then it starts again: only memory is at stake)


@dataclass(frozen=True)
class TraceFrame:
    line: int  # 1-based line in the trace file (index + 1 for binary formats)
    message: can.Message


def _frame(m: re.Match, path: str, lineno: int | None) -> Frame:
    ident, body = m["id"], m["body"]
    can_id = int(ident, 16)
    extended = len(ident) == 8
    if not extended and can_id > STD_ID_MAX:
        raise TraceError(path, lineno, f"11-bit id {ident} is above 7FF")
    if extended and can_id > EXT_ID_MAX:
        what = "an error frame" if can_id & CAN_ERR_FLAG else f"29-bit id {ident} is above 1FFFFFFF"
        raise TraceError(path, lineno, f"{what}: the bridge carries CAN 2.0 data and remote frames only")
    if body.startswith("#"):
        raise TraceError(path, lineno, "a CAN FD frame: the bridge carries CAN 2.0 frames only")
    if body.startswith("R"):
        return Frame(can_id, int(body[1:] or 0), b"", extended, True)
    if len(body) > 16:
        raise TraceError(path, lineno, f"{len(body) // 2} data bytes: classic CAN carries at most 8")
    data = bytes.fromhex(body)
    return Frame(can_id, len(data), data, extended)


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
        raise TraceError(path, lineno, f"not a candump -L frame: {line.strip()[:80]!r}")
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
                 growing: bool = False, cache_size: int = FRAME_CACHE) -> Iterator[tuple[int, int, str, Frame]]:
    """(line number, t_ns, interface, frame) of every frame line of a candump -L file.
    drops: filled with the frames candump says the kernel dropped, per interface (DROPCOUNT).
    growing: candump may still be writing, so a last line without its newline is skipped.
    cache_size: distinct frame texts kept for sharing (a reader in bounded memory keeps fewer)."""
    cache: dict[tuple[str, str], Frame] = {}
    with open(path, errors="replace") as f:
        for lineno, raw in enumerate(f, 1):
            if growing and not raw.endswith("\n"):
                return
            if len(cache) > cache_size:
                cache.clear()
            parsed = parse_line(raw.lstrip(), str(path), lineno, cache)
            if parsed is None:
                if drops is not None and (m := DROPCOUNT.match(raw)):
                    drops[m[2]] = drops.get(m[2], 0) + int(m[1])
            elif interface is None or parsed[1] == interface:
                yield (lineno, *parsed)


def _read_candump_trace(path: Path, interfaces: set[str] | None) -> tuple[list[int], list[can.Message]]:
    lines: list[int] = []
    messages: list[can.Message] = []
    last_ns = None
    for lineno, t_ns, iface, frame in iter_candump(path):
        if interfaces is not None and iface not in interfaces:
            raise TraceError(str(path), lineno, f"interface '{iface}' is not one of "
                             f"{sorted(interfaces)} (remap it in the scenario)")
        if last_ns is not None and t_ns < last_ns:
            raise TraceError(str(path), lineno, "timestamp earlier than the line before")
        last_ns = t_ns
        if len(messages) >= MAX_TRACE_FRAMES:
            raise TraceError(str(path), lineno, f"more than {MAX_TRACE_FRAMES} frames: split the trace")
        lines.append(lineno)
        messages.append(can.Message(timestamp=t_ns / 1e9, arbitration_id=frame.can_id, is_extended_id=frame.extended,
                                    is_remote_frame=frame.remote, dlc=frame.dlc, data=frame.data, channel=iface))
    return lines, messages


def read_trace(path: str | Path, interfaces: set[str] | None = None) -> list[TraceFrame]:
    """All frames of a trace, in order, each with the line it came from.
    interfaces: names the trace may use (None: any)."""
    path = Path(path)
    if not path.is_file():
        raise TraceError(str(path), None, "no such trace file")
    is_candump = path.suffix in (".log", ".candump", "")
    try:
        if is_candump:
            lines, messages = _read_candump_trace(path, interfaces)
        else:
            messages = list(can.LogReader(str(path)))
            lines = list(range(1, len(messages) + 1))
    except TraceError:
        raise
    except Exception as e:  # python-can raises many kinds for bad files
        raise TraceError(str(path), None, f"python-can cannot read it: {e}") from None
    if not messages:
        raise TraceError(str(path), None, "no frames in trace")
    return [TraceFrame(line, msg) for line, msg in zip(lines, messages, strict=True)]
