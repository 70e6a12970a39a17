"""python-can's BLF reader, with the bus events it skips without a word: an error frame stored
as a CAN_ERROR or CAN_FD_ERROR_64 object (some loggers' way, and CANoe's on a CAN FD channel;
python-can reads only CAN_ERROR_EXT ones) and an
overload frame (CAN_OVERLOAD) are read as python-can reads a CAN_ERROR_EXT, an error-flagged
can.Message, so that a BLF's error frames are refused and counted as every other format's are
(canbench.trace)."""
from __future__ import annotations

import re
import struct
from collections import deque
from collections.abc import Iterator
from decimal import Decimal

import can
from can.io import blf

# Vector's object types python-can's reader passes over. An overload frame is read as an error
# frame too: like one, it is a bus event with no id or data a replay could send, and the kernel
# reports it as one (CAN_ERR_PROT_OVERLOAD), so candump -e's recording of the bus counts it as one.
# CAN_FD_ERROR_64: the error frame CANoe and CANalyzer store on a channel in CAN FD mode (which
# carries classic frames too).
CAN_ERROR, CAN_OVERLOAD, CAN_FD_ERROR_64 = 2, 3, 104
# each begins with its channel (from 1): VBLCANErrorFrame and VBLCANOverloadFrame a WORD, VBLCANFDErrorFrame64 a BYTE
CHANNEL = {CAN_ERROR: struct.Struct("<H"), CAN_OVERLOAD: struct.Struct("<H"), CAN_FD_ERROR_64: struct.Struct("<B")}
BUS_EVENTS = tuple(CHANNEL)
# an object header of these types: none in the data, no object of them starts in it (a quick test)
BUS_EVENT_HEADER = re.compile(rb"LOBJ.{8}[\x02\x03\x68]\x00\x00\x00", re.DOTALL)
HEADER_SIZES = {1: blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size,
                2: blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V2_STRUCT.size}


class BLFReader(blf.BLFReader):
    """python-can's reader, that also yields Message(is_error_frame=True) for CAN_ERROR,
    CAN_FD_ERROR_64 and CAN_OVERLOAD objects, in their place among the frames.

    Two internals of python-can 4.6.1's reader make that possible, pinned by
    test_python_can_blf_internals_it_relies_on (an upgrade that changes them fails it):
    _parse_data(data) reads each container's data (after what the one before left of an object
    that goes on in it: _tail), and sets self._pos to the end of the object before the one it
    reads. So at each frame it yields, the bus events before self._pos come first; where it
    stops, those at or after it are left in _tail and read with the next container."""

    def _parse_data(self, data: bytes) -> Iterator[can.Message]:
        frames = super()._parse_data(data)
        if not BUS_EVENT_HEADER.search(data):  # most recordings: python-can's reader alone, at its speed
            yield from frames
            return
        events = deque(self._bus_events(data))
        try:
            for frame in frames:
                while events and events[0][0] < self._pos:
                    yield events.popleft()[1]
                yield frame
        except struct.error:  # python-can's 'the rest is in the next container', caught by its caller
            yield from (event for pos, event in events if pos < self._pos)
            raise
        yield from (event for pos, event in events if pos < self._pos)

    def _bus_events(self, data: bytes) -> Iterator[tuple[int, can.Message]]:
        """(where its object starts, the error frame) of each whole bus event object (BUS_EVENTS)
        in data, walking the objects as python-can's _parse_data does; the rest of what it reads or
        refuses (a stray byte, an unknown header version) is python-can's to say."""
        pos, end = 0, len(data)
        while pos + blf.OBJ_HEADER_BASE_STRUCT.size <= end:
            pos = data.find(b"LOBJ", pos, pos + 8)  # objects are padded
            if pos < 0 or pos + blf.OBJ_HEADER_BASE_STRUCT.size > end:
                return
            _, _, version, size, kind = blf.OBJ_HEADER_BASE_STRUCT.unpack_from(data, pos)
            if size < blf.OBJ_HEADER_BASE_STRUCT.size or pos + size > end:
                return  # python-can's own error, or an object that goes on in the next container
            body = pos + HEADER_SIZES.get(version, 0)
            if kind in BUS_EVENTS and version in HEADER_SIZES and body + CHANNEL[kind].size <= pos + size:
                header = blf.OBJ_HEADER_V1_STRUCT if version == 1 else blf.OBJ_HEADER_V2_STRUCT
                flags, _, _, stamp = header.unpack_from(data, pos + blf.OBJ_HEADER_BASE_STRUCT.size)
                factor = blf.TIME_TEN_MICS_FACTOR if flags == blf.TIME_TEN_MICS else blf.TIME_ONE_NANS_FACTOR
                yield pos, can.Message(timestamp=float(Decimal(stamp) * factor) + self.start_timestamp,
                                       is_error_frame=True, channel=CHANNEL[kind].unpack_from(data, body)[0] - 1)
            pos += size
