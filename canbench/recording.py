"""recording.mcap of a bench run, in ROS 2's own encoding so that Foxglove, Rerun
(`rerun recording.mcap`, `rerun mcap convert`) and ROS 2 bag tooling open it
natively: every message is CDR, every schema a ROS 2 .msg definition
(schema encoding ros2msg, message encoding cdr; profile ros2).

Channels (header.stamp = log time; header.frame_id = the bus):
  /can/<bus>                     can_msgs/msg/Frame  every frame on the bus (log time: bus timestamp)
  /zenoh/<bus>                   can_msgs/msg/Frame  every frame the consumer received (log time: receive)
  /commands/<bus>                can_msgs/msg/Frame  every command put on the tx key (log time: put)
  /latency/<bus>                 std_msgs/msg/Float64  CAN -> Zenoh latency of each matched frame, ms
  /signals/<bus>/<msg>/<signal>  std_msgs/msg/Float64  DBC-decoded signals of bus frames (Foxglove plots
                                                      `/signals/vcan0/EngineData/EngineSpeed.data`)
  /signals_zenoh/<bus>/<msg>/<signal>  std_msgs/msg/Float64  the same decoded from the frames received on
                                                      Zenoh (log time: receive), so a corrupted signal shows
                                                      next to what the bus carried
Signals are decoded with the bus's DBC (buses[].dbc, else the scenario's dbc); a J1939 group
from another source than the DBC's id (dbc.message_of) is <msg>_<id>, one channel per sender.

`canbench view recording.mcap` reads it back through the live viewer's decoders
and loggers (view_mcap): the same entities as a live run."""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import Writer

from . import ros2, ros2_msgs, wire
from .dbc import decode_signals, load_dbc
from .errors import InputError

if TYPE_CHECKING:  # the viewer's side needs rerun-sdk, writing a recording does not
    from .oracle import Observed
    from .run import RunResult
    from .viewer_types import Context

FRAME, FLOAT64 = "can_msgs/msg/Frame", "std_msgs/msg/Float64"


def can_frame_msg(bus: str, t_ns: int, f: wire.Frame) -> ros2_msgs.CanFrame:
    stamp = ros2_msgs.Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
    return ros2_msgs.CanFrame(header=ros2_msgs.Header(stamp=stamp, frame_id=bus), id=f.can_id, is_rtr=f.remote,
                              is_extended=f.extended, dlc=f.dlc,
                              data=(b"" if f.remote else f.data).ljust(8, b"\0"))  # type: ignore[arg-type]


class Ros2McapWriter:
    """Channels created as topics first appear, one schema per ROS 2 type."""

    def __init__(self, out):
        self.writer = Writer(out)
        self.writer.start(profile="ros2", library="canbench")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.seqs: dict[str, int] = {}

    def write(self, topic: str, ros_type: str, t_ns: int, msg) -> None:
        if topic not in self.channels:
            if ros_type not in self.schemas:
                self.schemas[ros_type] = self.writer.register_schema(
                    ros_type, "ros2msg", ros2.msg_definition(ros_type).encode())
            # the ros2 profile's required channel user data (MCAP spec, profiles/ros2.md); empty: no
            # publisher offered a QoS to the bench's recording (rosbag2 then plays with its default)
            self.channels[topic] = self.writer.register_channel(topic, "cdr", self.schemas[ros_type],
                                                                metadata={"offered_qos_profiles": ""})
        self.seqs[topic] = self.seqs.get(topic, 0) + 1
        self.writer.add_message(self.channels[topic], log_time=t_ns, publish_time=t_ns, sequence=self.seqs[topic],
                                data=msg.serialize())

    def frame(self, topic: str, bus: str, o: Observed) -> None:
        self.write(topic, FRAME, o.t_ns, can_frame_msg(bus, o.t_ns, o.frame))


class TopicNames:
    """ROS 2 topic names for a database's message and signal names: a KCD, SYM or ARXML file may
    name them with spaces, dashes or dots, or a digit first, which no ROS 2 topic has (ros2 bag play
    cannot publish on one). Each part not of [A-Za-z0-9_] or led by a digit is made one ('Engine
    Data' -> Engine_Data, '2nd.Gear' -> _2nd_Gear); two names that would be one topic stay apart
    (a suffix)."""

    def __init__(self) -> None:
        self.of: dict[tuple[str, ...], str] = {}
        self.taken: set[str] = set()

    def topic(self, prefix: str, *parts: str) -> str:
        key = (prefix, *parts)
        name = self.of.get(key)
        if name is None:
            name = prefix + "".join("/" + _topic_part(p) for p in parts)
            base, n = name, 1
            while name in self.taken:
                n += 1
                name = f"{base}_{n}"
            self.of[key] = name
            self.taken.add(name)
        return name


def _topic_part(name: str) -> str:
    part = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    return "_" + part if part[0].isdigit() else part


def _signals(w: Ros2McapWriter, names: TopicNames, prefix: str, db, o: Observed) -> None:
    if db is not None and not o.frame.remote and (signals := decode_signals(db, o.frame)):
        message = signals[0]
        if o.frame.can_id != db.get_message_by_name(message).frame_id:  # a J1939 group's other sender
            message = f"{message}_{wire.id_hex(o.frame.can_id, o.frame.extended)}"
        for name, value in signals[1].items():
            w.write(names.topic(prefix, message, name), FLOAT64, o.t_ns, ros2_msgs.Float64(value))


def write_mcap(result: RunResult, path: Path, dbc=None) -> None:
    """dbc: the DBC (cantools) of buses the scenario gives none of their own."""
    bus_dbcs = getattr(result.scenario, "bus_dbcs", {})
    with open(path, "wb") as out:
        w = Ros2McapWriter(out)
        names = TopicNames()
        for b in result.buses:
            db = load_dbc(bus_dbcs[b.bus]) if b.bus in bus_dbcs else dbc
            for o in b.bus_frames:
                w.frame(f"/can/{b.bus}", b.bus, o)
                _signals(w, names, f"/signals/{b.bus}", db, o)
            latency_of = {r.index: (r.t_ns - s.t_ns) / 1e6 for s, r in b.comparison.matched}
            for o in b.zenoh_frames:
                w.frame(f"/zenoh/{b.bus}", b.bus, o)
                _signals(w, names, f"/signals_zenoh/{b.bus}", db, o)
                if o.index in latency_of:
                    w.write(f"/latency/{b.bus}", FLOAT64, o.t_ns, ros2_msgs.Float64(latency_of[o.index]))
            for o in b.commands:
                w.frame(f"/commands/{b.bus}", b.bus, o)
        w.writer.add_metadata("canbench.run", {"run_id": result.run_id, "scenario": result.scenario.name,
                                               "passed": str(result.metrics.get("passed"))})
        w.writer.finish()


def recorded_definition(schema) -> tuple[str | None, bool]:
    """(how a recording's definition of a type differs from the viewer's, or None; whether it is
    Humble's where that is not Jazzy's, ros2_msgs.HUMBLE_VARIANTS: read with that)."""
    from .ros2 import definition_difference
    text = schema.data.decode("utf-8", "replace")
    try:
        difference = definition_difference(schema.name, text)
    except Exception as e:  # noqa: BLE001 - a damaged schema text is another definition, never a traceback
        return f"its schema text cannot be read: {type(e).__name__}: {e}", False
    variant = ros2_msgs.HUMBLE_VARIANTS.get(schema.name)
    if difference and variant and not definition_difference(schema.name, text, variant):
        return None, True
    return difference, False


@dataclass
class Viewed:
    """What `canbench view FILE.mcap` made of a recording."""
    logged: int = 0
    malformed: int = 0
    other_definition: int = 0  # of a type whose recorded definition is not the viewer's
    cut: str | None = None  # why the reading stopped early: a cut or damaged recording


MCAP_MAGIC = b"\x89MCAP0\r\n"


def recorded_messages(f, path: Path):
    """(schema, channel, message) of an MCAP file, in log-time order by its index; a file without
    its end (a recording cut short: power lost, the recorder killed, a copy interrupted) record by
    record up to the cut. The iterator raises at a cut or a damaged chunk (CRCs are checked: a
    flipped bit showed wrong values without a word); a file that is no MCAP is an InputError."""
    if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise InputError(str(path), None, "not an MCAP file (canbench view reads MCAP recordings; "
                                          "a CAN trace goes through canbench summarise or a scenario)")
    f.seek(0)
    try:
        reader = make_reader(f, validate_crcs=True)
        reader.get_summary()  # at the file's end: raises where that end is missing
        return reader.iter_messages()
    except Exception:  # noqa: BLE001 - EndOfFile, a cut footer, ...: read what is there, in order
        f.seek(0)  # in the file's order (in log-time order it would hold every message back until the end)
        return NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False)


def view_mcap(path: Path, ctx: Context) -> Viewed:
    """Every ROS 2 (CDR) channel of an MCAP file through the viewer's loggers, at the topic's
    path (/can/vcan0 -> can/vcan0/<id>/raw). A channel whose recorded definition of its type is
    not the viewer's (an older distribution's, a same-named custom type) is not decoded, said once
    under discovery/errors; a cut or damaged recording is shown up to the cut and said."""
    import rerun as rr

    from .viewer_types import LOGGERS
    from .viewer_types.can import CanColumns
    from .viewer_types.markers import expire
    from .viewer_types.registry import ScalarColumns, set_sample_time
    viewed = Viewed()
    scalars = ctx.scalars = ScalarColumns()  # sent per entity when due
    can = ctx.can = CanColumns(ctx.dbc, ctx.bus_dbcs)  # can_msgs' frames, the same
    definitions: dict[int, tuple[str | None, bool]] = {}  # schema id -> recorded_definition
    told: set[int] = set()  # channels of another definition already said
    try:
        with open(path, "rb") as f:
            messages = recorded_messages(f, path)
            while True:
                try:
                    schema, channel, message = next(messages)
                except StopIteration:
                    break
                except Exception as e:  # noqa: BLE001 - a cut or damaged chunk: what came before is shown
                    cut = ("a record ends past the file's end" if isinstance(e, EndOfFile | struct.error)
                           else f"{type(e).__name__}: {e}")
                    viewed.cut = f"{cut}, after {viewed.logged + viewed.malformed + viewed.other_definition} messages"
                    rr.log("discovery/errors", rr.TextLog(f"{path}: the recording is cut or damaged "
                                                          f"({viewed.cut}): shown up to there"))
                    break
                if schema is None or schema.encoding != "ros2msg" or schema.name not in LOGGERS:
                    continue
                if schema.id not in definitions:
                    definitions[schema.id] = recorded_definition(schema)
                difference, humble = definitions[schema.id]
                if difference:
                    if channel.id not in told:
                        told.add(channel.id)
                        rr.log("discovery/errors", rr.TextLog(f"{channel.topic}: recorded with another definition "
                                                              f"of {schema.name} ({difference}): not decoded"))
                    viewed.other_definition += 1
                    continue
                ctx.t_ns, ctx.static = message.log_time, channel.topic == "/tf_static"
                try:
                    msg = ros2_msgs.decode(schema.name, message.data, humble)
                    ctx.stamp_ns = set_sample_time(message.log_time, msg)
                    LOGGERS[schema.name](ctx, channel.topic.strip("/"), msg)
                    viewed.logged += 1
                except Exception as e:  # noqa: BLE001 - as live: a bad message is shown and counted, never fatal
                    set_sample_time(message.log_time, None)
                    rr.log("discovery/errors", rr.TextLog(f"{channel.topic}: {e}"))
                    viewed.malformed += 1
                for columns in (can, scalars):
                    if columns.due():
                        columns.flush()
    finally:  # what was read is sent, however the reading ended (Ctrl-C too)
        can.flush()
        scalars.flush()
    expire(ctx)  # markers whose lifetime ends after the last message
    return viewed
