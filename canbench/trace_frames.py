"""A trace's frames in memory, held compactly: what a replay ECU or a command sends is read whole
before it starts (so reading costs nothing during the replay), and a TraceFrame of a python-can
Message takes about 900 bytes where its fields take about 35. So the frames are kept as columns
(line, stamp, id, kind, dlc, data) and each TraceFrame, or a replay's Message, is made when it is
read: a trace at the 10 000 000-frame limit fits in about 350 MB instead of 9 GB."""
from __future__ import annotations

from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import can

from .wire import Frame

_EXTENDED, _REMOTE = 1, 2
_SLOT = 8  # data bytes kept per frame: CAN 2.0 (a longer frame is refused before it is stored)


@dataclass(frozen=True)
class TraceFrame:
    line: int  # 1-based line in the trace file (index + 1 for binary formats)
    message: can.Message


class TraceFrames(Sequence[TraceFrame]):
    """Frames of one interface (channel) in trace order; append as read, index or iterate to use."""

    def __init__(self, channel: str | None = None) -> None:
        self.channel = channel
        self._lines = array("q")
        self._t_ns = array("q")
        self._ids = array("L")
        self._kinds = array("B")
        self._dlcs = array("B")
        self._lens = array("B")
        self._data = bytearray()

    def append(self, line: int, t_ns: int, frame: Frame) -> None:
        if len(frame.data) > _SLOT:
            raise ValueError(f"{len(frame.data)} data bytes: a CAN 2.0 frame has at most {_SLOT}")
        self._lines.append(line)
        self._t_ns.append(t_ns)
        self._ids.append(frame.can_id)
        self._kinds.append((_EXTENDED if frame.extended else 0) | (_REMOTE if frame.remote else 0))
        self._dlcs.append(frame.dlc)
        self._lens.append(len(frame.data))
        self._data += frame.data.ljust(_SLOT, b"\0")

    def __len__(self) -> int:
        return len(self._lines)

    def line(self, i: int) -> int:
        return self._lines[i]

    def t_ns(self, i: int) -> int:
        return self._t_ns[i]

    def key(self, i: int) -> tuple[int, bool]:
        """(id, 29-bit) of the i-th frame."""
        return self._ids[i], bool(self._kinds[i] & _EXTENDED)

    def keys(self) -> Iterator[tuple[int, bool]]:
        return zip(self._ids, (bool(k & _EXTENDED) for k in self._kinds), strict=True)

    def message(self, i: int, timestamp: float, arbitration_id: int, channel: str | None) -> can.Message:
        """The i-th frame as a Message sent at timestamp, with that id, on that channel (a replay's:
        made from the columns at once, not through a TraceFrame)."""
        kind, at = self._kinds[i], i * _SLOT
        return can.Message(timestamp=timestamp, arbitration_id=arbitration_id, is_extended_id=bool(kind & _EXTENDED),
                           is_remote_frame=bool(kind & _REMOTE), dlc=self._dlcs[i],
                           data=self._data[at:at + self._lens[i]], channel=channel)

    def sent(self, origin_ns: int, offset_s: float, scale: float, id_remap: dict[int, int],
             channel: str | None) -> Iterator[tuple[int, can.Message]]:
        """(line, Message) of every frame as a replay sends it: at offset_s + (its stamp - origin_ns)
        in s x scale (the difference taken in integer ns: epoch stamps as floats are 0.2 us apart),
        its id remapped, on channel; made from the columns as it goes (the replay's hot path)."""
        data, message, get = self._data, can.Message, id_remap.get
        columns = (self._lines, self._t_ns, self._ids, self._kinds, self._dlcs, self._lens,
                   range(0, len(self._data), _SLOT))
        for line, stamp, can_id, kind, dlc, size, at in zip(*columns, strict=True):
            yield line, message(timestamp=offset_s + (stamp - origin_ns) / 1e9 * scale,
                                arbitration_id=get(can_id, can_id), is_extended_id=kind & _EXTENDED == _EXTENDED,
                                is_remote_frame=kind & _REMOTE == _REMOTE, dlc=dlc, data=data[at:at + size],
                                channel=channel)

    def _at(self, i: int) -> TraceFrame:
        return TraceFrame(self._lines[i], self.message(i, self._t_ns[i] / 1e9, self._ids[i], self.channel))

    @overload
    def __getitem__(self, i: int) -> TraceFrame: ...

    @overload
    def __getitem__(self, i: slice) -> list[TraceFrame]: ...

    def __getitem__(self, i: int | slice) -> TraceFrame | list[TraceFrame]:
        if isinstance(i, slice):
            return [self._at(k) for k in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError("trace frame index out of range")
        return self._at(i)

    def __iter__(self) -> Iterator[TraceFrame]:
        return (self._at(i) for i in range(len(self)))
