"""CAN traces: candump -L logs are checked line by line (so every problem has
a file:line) and then read with python-can's LogReader, like every other
format it knows (.asc .blf .csv .trc .mf4)."""
from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import can

from .errors import TraceError

# candump -L grammar (can-utils lib.h), e.g. "(1700000000.123456) vcan0 123#DEADBEEF":
#   (<sec>.<usec|nsec>) <iface> <id>#<data>     id: 3 hex = 11-bit, 8 hex = 29-bit
#   <id>#R[<dlc>]  remote frame          <id>##<flags><data>  CAN FD
CANDUMP_LINE = re.compile(
    r"^\((?P<ts>\d+\.\d+)\)\s+(?P<iface>[A-Za-z0-9_.-]+)\s+"
    r"(?P<id>[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#(?P<body>(?:R[0-9]?|#[0-9A-Fa-f][0-9A-Fa-f]*|(?:[0-9A-Fa-f]{2})*))"
    r"(?:\s+[TR])?\s*$")
MAX_TRACE_FRAMES = 10_000_000


@dataclass(frozen=True)
class TraceFrame:
    line: int  # 1-based line in the trace file (index + 1 for binary formats)
    message: can.Message


def _check_candump(path: Path, interfaces: set[str] | None) -> None:
    last_ts = None
    frames = 0
    with open(path, errors="replace") as f:
        for lineno, raw in enumerate(f, 1):
            line = raw.strip()
            if not line or not line.startswith("("):
                continue  # canplayer ignores lines that do not start with '(' too
            m = CANDUMP_LINE.match(line)
            if not m:
                raise TraceError(str(path), lineno, f"not a candump -L frame: {line[:80]!r}")
            can_id = int(m["id"], 16)
            if len(m["id"]) == 3 and can_id > 0x7FF:
                raise TraceError(str(path), lineno, f"11-bit id {m['id']} is above 7FF")
            if len(m["id"]) == 8 and can_id > 0x1FFFFFFF and not can_id & 0x20000000:
                raise TraceError(str(path), lineno, f"29-bit id {m['id']} is above 1FFFFFFF")
            body = m["body"]
            if not body.startswith(("R", "#")) and len(body) > 16:
                raise TraceError(str(path), lineno, f"{len(body) // 2} data bytes: classic CAN carries at most 8")
            if interfaces is not None and m["iface"] not in interfaces:
                raise TraceError(str(path), lineno, f"interface '{m['iface']}' is not one of "
                                 f"{sorted(interfaces)} (remap it in the scenario)")
            ts = float(m["ts"])
            if last_ts is not None and ts < last_ts:
                raise TraceError(str(path), lineno, f"timestamp {m['ts']} is earlier than the line before")
            last_ts = ts
            frames += 1
            if frames > MAX_TRACE_FRAMES:
                raise TraceError(str(path), lineno, f"more than {MAX_TRACE_FRAMES} frames: split the trace")
    if frames == 0:
        raise TraceError(str(path), None, "no frames in trace")


def read_trace(path: str | Path, interfaces: set[str] | None = None) -> list[TraceFrame]:
    """All frames of a trace, in order, each with the line it came from.
    interfaces: names the trace may use (None: any)."""
    path = Path(path)
    if not path.is_file():
        raise TraceError(str(path), None, "no such trace file")
    is_candump = path.suffix in (".log", ".candump", "")
    try:
        if is_candump:
            _check_candump(path, interfaces)
            # canplayer skips lines that do not start with '(' (comments); python-can does not
            numbered = [(n, raw.strip()) for n, raw in enumerate(open(path, errors="replace"), 1)
                        if raw.strip().startswith("(")]
            lines = [n for n, _ in numbered]
            messages = list(can.CanutilsLogReader(io.StringIO("\n".join(text for _, text in numbered) + "\n")))
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
