"""The registry of the viewer's ROS 2 loggers and the Context they share (see the package's
docstring for how to add a type)."""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rerun as rr

Logger = Callable[["Context", str, Any], None]
LOGGERS: dict[str, Logger] = {}


def logger(type_name: str) -> Callable[[Logger], Logger]:
    def register(fn: Logger) -> Logger:
        if type_name in LOGGERS:
            raise ValueError(f"two loggers for {type_name}")
        LOGGERS[type_name] = fn
        return fn
    return register


class Context:
    """What loggers share across messages: the DBC (and a bus's own, bus_dbcs: bus -> DBC, for
    the buses that have one), the TF tree (child -> parent), whether a topic's entities are
    static (/tf_static), the markers whose lifetime is running."""

    def __init__(self, dbc=None, bus_dbcs: dict | None = None):
        self.dbc = dbc
        self.bus_dbcs = dict(bus_dbcs or {})
        self.parents: dict[str, str] = {}
        self.tf_entities: dict[str, str] = {}  # frame -> the entity its transforms are logged at, for good
        self.frames_of: dict[str, str] = {}  # entity path -> the frame last declared for it
        self.static = False  # set per sample by the viewer
        self.t_ns = 0  # the sample's receive time, also set per sample
        self.expiries: dict[str, int] = {}  # marker entity -> when its lifetime ends (ns, receive time)
        self.domain = ""  # the sample's ROS domain other than 0 ('domain7'), set per sample: a TF tree each
        self.stamp_ns: int | None = None  # the sample's header stamp (set_sample_time), set per sample
        self.scalars: ScalarColumns | None = None  # when set, scalars are sent per entity at its flush
        self.can: Any = None  # when set, the CanColumns frames are collected in (viewer_types.can)
        self.texts: dict[str, int] = {}  # entity -> a hash of the text and level it last logged (TEXTS_KEPT)

    def frame(self, frame_id: str) -> str:
        """A frame's name: as tf2 names it, and of its domain's tree (domain7/odom) for a domain other
        than 0 (two robots both have an odom and a base_link)."""
        name = frame_name(frame_id)
        return f"{self.domain}/{name}" if name and self.domain else name

    def frame_path(self, frame: str) -> str:
        """tf/[<domain>/]<root>/.../<frame> as far as the tree is known (a cycle stops the walk);
        frame as frame() names it."""
        chain = [frame]
        while (parent := self.parents.get(chain[-1])) is not None and parent not in chain:
            chain.append(parent)
        prefix = f"{self.domain}/" if self.domain else ""
        return "tf/" + prefix + "/".join(f.removeprefix(prefix) for f in reversed(chain))

    def log(self, path: str, *archetypes, frame: str = "", named: bool = False) -> None:
        """rr.log, plus the entity's coordinate frame (header.frame_id) whenever it changes; named:
        frame is a name pose() gave (an entity's own frame), not a header's frame_id to name."""
        frame = frame if named else self.frame(frame)
        if frame and self.frames_of.get(path) != frame:
            self.frames_of[path] = frame
            archetypes = (*archetypes, rr.CoordinateFrame(frame))
        rr.log(path, *archetypes, static=self.static)

    def pose(self, path: str, position, orientation, frame: str) -> None:
        """A pose as a Transform3D: from its header's frame to a frame named after the entity,
        in which the entity draws its axes (without a frame: relative to the entity's parent)."""
        frame = self.frame(frame)
        t = [position.x, position.y, position.z]
        q = rr.Quaternion(xyzw=[orientation.x, orientation.y, orientation.z, orientation.w])
        transform = rr.Transform3D(translation=t, quaternion=q, parent_frame=frame or None,
                                   child_frame=path if frame else None)
        rr.log(path, transform, rr.TransformAxes3D(0.5),
               *([rr.CoordinateFrame(path)] if frame else []), static=self.static)

    def scalar(self, path: str, value: float) -> None:
        if self.scalars is None:
            rr.log(path, rr.Scalars(float(value)))
        else:
            self.scalars.add(path, self.t_ns, self.stamp_ns, float(value))


FLUSH_AFTER_S = 0.1  # how long scalars wait to be sent together (a live plot lags by at most that)
FLUSH_VALUES = 100_000  # or how many
FEW_ROWS = 4  # an entity's rows fewer than this go through rr.log, which Rerun batches (a 10 Hz signal)


def log_rows(path: str, times: list[int], stamps: Sequence[int | None] | None, archetypes: list) -> None:
    """A few rows of one entity through rr.log at their own times: a one-row send_columns skips
    Rerun's batching (a CAN id's or a 1 Hz topic's values, one row per flush: a .rrd 20 times
    larger). Leaves the timelines at the last row's: what is logged next sets its own."""
    for i, archetype in enumerate(archetypes):
        rr.set_time("time", timestamp=np.datetime64(times[i], "ns"))
        stamp = stamps[i] if stamps else None
        if stamp is None:
            rr.disable_timeline("header_stamp")
        else:
            rr.set_time("header_stamp", timestamp=np.datetime64(stamp, "ns"))
        rr.log(path, archetype)


class Pending:
    """How many values wait to be sent and since when: due after FLUSH_VALUES of them or, with any
    waiting, FLUSH_AFTER_S (a live plot lags by at most that)."""

    def __init__(self) -> None:
        self.count = 0
        self.since = time.monotonic()

    def due(self) -> bool:
        return self.count >= FLUSH_VALUES or (self.count > 0 and time.monotonic() - self.since >= FLUSH_AFTER_S)

    def sent(self) -> None:
        self.count, self.since = 0, time.monotonic()


def send_entity(path: str, archetype, field: str, times: list[int], values: list,
                stamps: Sequence[int] | None = None) -> None:
    """One entity's rows: a few through rr.log (log_rows), more as one column of the archetype's
    `field` (send_columns) on `time` and, given stamps, `header_stamp`."""
    if len(values) < FEW_ROWS:
        log_rows(path, times, stamps, [archetype(v) for v in values])
        return
    indexes = [time_column(times)]
    if stamps:
        indexes.append(rr.TimeColumn("header_stamp", timestamp=np.asarray(stamps, "datetime64[ns]")))
    rr.send_columns(path, indexes=indexes, columns=archetype.columns(**{field: values}))


def time_column(times_ns: list[int]) -> rr.TimeColumn:
    # as datetime64[ns]: a list of float seconds costs Rerun's converter 20 times more per row
    return rr.TimeColumn("time", timestamp=np.asarray(times_ns, dtype="datetime64[ns]"))


class ScalarColumns:
    """Scalars of many messages, sent one column per entity (send_columns) when due (Pending): an
    rr.log per value costs 25-35 µs, and a robot's /joint_states (30 joints, 3 values each, at a
    controller's 100-500 Hz) needed more than the logger thread has; a column per message would be
    worse (a one-row send_columns skips Rerun's batching: twice the CPU of an rr.log and a .rrd
    nine times larger)."""

    def __init__(self) -> None:
        self.series: dict[str, tuple[list[int], list[int | None], list[float]]] = {}
        self.pending = Pending()

    def add(self, path: str, t_ns: int, stamp_ns: int | None, value: float) -> None:
        times, stamps, values = self.series.setdefault(path, ([], [], []))
        times.append(t_ns)
        stamps.append(stamp_ns)
        values.append(value)
        self.pending.count += 1

    def due(self) -> bool:
        return self.pending.due()

    def flush(self) -> None:
        for path, (times, stamps, values) in self.series.items():
            # values on header_stamp too, and those of messages without one on `time` alone
            stamped = [i for i, s in enumerate(stamps) if s is not None]
            unstamped = [i for i, s in enumerate(stamps) if s is None]
            if stamped:
                send_entity(path, rr.Scalars, "scalars", [times[i] for i in stamped], [values[i] for i in stamped],
                            [s for s in stamps if s is not None])
            if unstamped:
                send_entity(path, rr.Scalars, "scalars", [times[i] for i in unstamped],
                            [values[i] for i in unstamped])
        self.series.clear()
        self.pending.sent()


def set_sample_time(t_ns: int, msg) -> int | None:
    """The timelines of what is logged next: `time`, the receive (or an MCAP's log) time, to the
    nanosecond; and `header_stamp`, the message's own header.stamp (source time, sim time: what
    RViz and tf2 go by; data and its TF line up there), absent for a message without one; that
    stamp (ns) or None."""
    rr.set_time("time", timestamp=np.datetime64(t_ns, "ns"))
    return header_stamp(getattr(getattr(msg, "header", None), "stamp", None))


def header_stamp(stamp) -> int | None:
    """What is logged next is at this builtin_interfaces/Time on `header_stamp` (None or 0: off it).
    Messages of several headers (a TF message, a MarkerArray) set it per transform or marker."""
    if stamp is not None and (stamp.sec or stamp.nanosec):
        ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        rr.set_time("header_stamp", timestamp=np.datetime64(ns, "ns"))
        return ns
    rr.disable_timeline("header_stamp")
    return None


def frame_name(frame_id: str) -> str:
    """A frame as tf2 names it: without one leading '/' (ROS 1's style, still sent; tf2's BufferCore
    strips it, so '/odom' and 'odom' are one frame)."""
    return frame_id[1:] if frame_id.startswith("/") else frame_id


def require(condition: bool, what: str) -> None:
    if not condition:
        raise ValueError(what)
