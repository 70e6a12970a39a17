"""CAN frames: the bridge's own frames and can_msgs/msg/Frame (the bridge's ROS 2
output, recording.mcap) alike -> <base>/<id>/raw (candump text) and, with a DBC,
<base>/<id>/<signal> (scalars), decoded with the DBC of the base's bus (its last part: can/rx/<bus>,
/can/<bus>) where one is given for it, else the default DBC. Frames are collected and sent to Rerun one column
per entity (send_columns): per-frame rr.log calls cost more than a busy bus allows."""
from __future__ import annotations

from collections import defaultdict

import rerun as rr

from .. import wire
from ..dbc import decode_signals
from .registry import Context, Pending, logger, send_entity

CAN_ERR_FLAG = 0x20000000  # linux/can.h: the id's flag of an error frame, as candump -e writes it


class CanColumns:
    """Frames grouped by entity, sent with their receive times when due (registry.Pending): one
    column per entity, a few rows through rr.log (registry.send_entity)."""

    def __init__(self, dbc, bus_dbcs: dict | None = None):
        self.dbc = dbc
        self.bus_dbcs = bus_dbcs or {}  # bus -> its own DBC (a scenario's buses[].dbc)
        self.raw: dict[str, tuple[list[int], list[str]]] = defaultdict(lambda: ([], []))
        self.signals: dict[str, tuple[list[int], list[float]]] = defaultdict(lambda: ([], []))
        self.pending = Pending()  # frames

    def due(self) -> bool:
        return self.pending.due()

    def add(self, base: str, t_ns: int, frames: list[wire.Frame]) -> None:
        bus = base.rsplit("/", 1)[-1]
        dbc = self.bus_dbcs.get(bus, self.dbc)
        self.pending.count += len(frames)
        for f in frames:
            ident = wire.id_hex(f.can_id, f.extended)
            times, texts = self.raw[f"{base}/{ident}/raw"]
            times.append(t_ns)
            texts.append(f.candump(bus).split(" ", 1)[1])
            if dbc is not None and not f.remote and (decoded := decode_signals(dbc, f)):
                for name, value in decoded[1].items():
                    times, values = self.signals[f"{base}/{ident}/{name}"]
                    times.append(t_ns)
                    values.append(value)

    def flush(self) -> int:
        """Sends what waits; the number of frames sent."""
        for path, (times, texts) in self.raw.items():
            send_entity(path, rr.TextLog, "text", times, texts)
        for path, (times, values) in self.signals.items():
            send_entity(path, rr.Scalars, "scalars", times, values)
        frames = sum(len(texts) for _, texts in self.raw.values())
        self.raw.clear()
        self.signals.clear()
        self.pending.sent()
        return frames


def frame_of(msg) -> wire.Frame:
    if msg.dlc > 8:
        raise ValueError(f"can_msgs/msg/Frame dlc {msg.dlc} > 8")
    return wire.Frame(msg.id, msg.dlc, bytes(msg.data)[:msg.dlc] if not msg.is_rtr else b"", msg.is_extended,
                      msg.is_rtr)


@logger("can_msgs/msg/Frame")
def log_frame(ctx: Context, path: str, msg) -> None:
    """Into the viewer's columns (ctx.can) when it keeps them, else sent at once. An error frame
    (is_error: ros2_socketcan's SocketCAN error frames, the id the error's class) is no message of
    any DBC: said at <base>/error as candump -e names it, never decoded as the id's message."""
    if msg.is_error:
        data = bytes(msg.data)[:8].hex().upper()
        ctx.log(f"{path}/error", rr.TextLog(f"{msg.id | CAN_ERR_FLAG:08X}#{data} (error class {msg.id:X})",
                                           level=rr.TextLogLevel.ERROR))
        return
    columns = ctx.can or CanColumns(ctx.dbc, ctx.bus_dbcs)
    columns.add(path, ctx.t_ns, [frame_of(msg)])
    if ctx.can is None:
        columns.flush()
