"""canbench view: see what is on a Zenoh network in Rerun.

Discovers, live, by liveliness tokens: the bridges (vehicle/can/bridges/<name>/
<bus>/<mode>) and ROS 2 entities (rmw_zenoh's @ros2_lv/**, a hermetic prefix
that wildcards never match, so it is asked for explicitly). Subscribes to the
bridges' CAN keys and to the selected ROS 2 topics, one subscriber each; the
callbacks hand samples to one logger thread through a queue. Loggers: bridge
CAN frames (16-byte format, batches) -> can/<bus>/<id>/raw (text) and, with a
DBC, can/<bus>/<id>/<signal> (scalars); ROS 2 types by the registry LOGGERS
(adding a type: one function and one registration line); unknown types are
listed under discovery/, never fatal.

  canbench view --zenoh-connect tcp/127.0.0.1:7447 --auto-subscribe [--dbc f.dbc] [--save out.rrd]
  canbench view reports/latest/recording.mcap

Network safety: multicast scouting is off; endpoints are explicit."""
from __future__ import annotations

import json
import queue
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import rerun as rr
import zenoh

from . import ros2, wire
from .report import decode_signals, load_dbc
from .viewer_args import DEFAULT_ENDPOINT


@dataclass
class Sample:
    t_ns: int
    key: str
    payload: bytes
    type_name: str = ""  # ROS 2 type for data keys; "" for the bridge's CAN keys


# ---- loggers ----

def _scalar(path: str, value: float) -> None:
    rr.log(path, rr.Scalars(float(value)))


def log_can_frames(base: str, frames: list[wire.Frame], dbc) -> None:
    for f in frames:
        ident = f"{f.can_id:08X}" if f.extended else f"{f.can_id:03X}"
        rr.log(f"{base}/{ident}/raw", rr.TextLog(f.candump(base.rsplit("/", 1)[-1]).split(" ", 1)[1]))
        if dbc is not None and not f.remote:
            decoded = decode_signals(dbc, f)
            if decoded:
                for name, value in decoded[1].items():
                    _scalar(f"{base}/{ident}/{name}", value)


def _log_string(path: str, msg, dbc) -> None:
    rr.log(path, rr.TextLog(msg.data))


def _log_field(field_name: str) -> Callable:
    def log(path: str, msg, dbc) -> None:
        _scalar(f"{path}/{field_name}", getattr(msg, field_name))
    return log


def _log_imu(path: str, msg, dbc) -> None:
    for group in ("orientation", "angular_velocity", "linear_acceleration"):
        vec = getattr(msg, group)
        for axis in ("x", "y", "z", "w"):
            if hasattr(vec, axis):
                _scalar(f"{path}/{group}/{axis}", getattr(vec, axis))


def _log_can_frame(path: str, msg, dbc) -> None:
    frame = wire.Frame(msg.id, msg.dlc, bytes(msg.data)[:msg.dlc] if not msg.is_rtr else b"", msg.is_extended,
                       msg.is_rtr)
    log_can_frames(path, [frame], dbc)


LOGGERS: dict[str, Callable] = {
    "std_msgs/msg/String": _log_string,
    "sensor_msgs/msg/Temperature": _log_field("temperature"),
    "sensor_msgs/msg/FluidPressure": _log_field("fluid_pressure"),
    "sensor_msgs/msg/RelativeHumidity": _log_field("relative_humidity"),
    "sensor_msgs/msg/Illuminance": _log_field("illuminance"),
    "sensor_msgs/msg/Imu": _log_imu,
    "can_msgs/msg/Frame": _log_can_frame,
}


def read_rrd(path: Path) -> dict[str, list]:
    """entity path -> the values logged there (scalars or text), read back with Rerun's own
    reader: what tests and nightly scripts check a recording with."""
    from rerun.chunk import RrdReader
    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        for column in ("Scalars:scalars", "TextLog:text"):
            if column in batch.schema.names:
                out.setdefault(str(chunk.entity_path), []).extend(v[0] for v in batch.column(column).to_pylist())
    return out


# ---- live viewer ----

class Viewer:
    def __init__(self, session: zenoh.Session, topics: list[str], auto_subscribe: bool, dbc=None,
                 prefix: str = "vehicle/can"):
        self.session, self.topics, self.auto, self.dbc, self.prefix = session, topics, auto_subscribe, dbc, prefix
        self.samples: queue.Queue[Sample | None] = queue.Queue(maxsize=100_000)
        self.entities: dict[str, ros2.Entity] = {}
        self.bridges: set[str] = set()
        self.subscribers: dict[str, object] = {}
        self.dropped = 0
        self.logged = 0
        self.buses: set[str] = set()
        self.lock = threading.Lock()

    def _enqueue(self, sample: Sample) -> None:
        try:
            self.samples.put_nowait(sample)
        except queue.Full:
            self.dropped += 1  # a viewer never slows the network down; counted

    def start(self) -> None:
        self.logger = threading.Thread(target=self._log_loop, daemon=True, name="loggers")
        self.logger.start()
        key = f"{self.prefix}/**"
        self.subscribers[key] = self.session.declare_subscriber(
            key, lambda s: self._enqueue(Sample(time.time_ns(), str(s.key_expr), s.payload.to_bytes())))
        self.lv_bridges = self.session.liveliness().declare_subscriber(
            f"{self.prefix}/bridges/**", self._on_bridge_token, history=True)
        self.lv_ros = self.session.liveliness().declare_subscriber(
            f"{ros2.LIVELINESS_PREFIX}/**", self._on_ros_token, history=True)
        # after the subscribers: whoever sees this token knows they are in place; the
        # queryable answers how much was logged (tests and scripts wait on it, never sleep)
        me = f"canbench/viewers/{self.session.info.zid()}"
        self.stats_queryable = self.session.declare_queryable(f"{me}/stats", self._on_stats_query)
        self.token = self.session.liveliness().declare_token(me)

    def _on_stats_query(self, query: zenoh.Query) -> None:
        with self.lock:
            stats = {"logged": self.logged, "dropped": self.dropped, "bridges": sorted(self.bridges),
                     "ros2_entities": len(self.entities), "subscriptions": sorted(self.subscribers)}
        query.reply(query.key_expr, json.dumps(stats))

    def _on_bridge_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        alive = sample.kind == zenoh.SampleKind.PUT
        with self.lock:
            (self.bridges.add if alive else self.bridges.discard)(key)
            # vehicle/can/bridges/<name>/<bus>/<mode>: the bus a single-bus bridge's keys stand for
            self.buses = {k.split("/")[-2] for k in self.bridges}
        rr.log("discovery/bridges", rr.TextLog(f"{'+' if alive else '-'} {key}"))

    def _on_ros_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            entity = ros2.parse_token(key)
        except ros2.TokenError as e:
            rr.log("discovery/ros2", rr.TextLog(f"unparsable token: {e}"))
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        supported = entity.type_name in LOGGERS
        rr.log("discovery/ros2", rr.TextLog(
            f"{'+' if alive else '-'} {ros2.KINDS[entity.kind]} {entity.namespace.rstrip('/')}/{entity.node} "
            f"{entity.topic} [{entity.type_name or '-'}]" + ("" if supported or not entity.topic else " (no logger)")))
        with self.lock:
            if alive:
                self.entities[key] = entity
            else:
                self.entities.pop(key, None)
            wanted = entity.kind == "MP" and supported and (self.auto or entity.topic in self.topics)
            if alive and wanted and entity.data_key not in self.subscribers:
                self.subscribers[entity.data_key] = self.session.declare_subscriber(
                    entity.data_key, self._ros_callback(entity.type_name))

    def _ros_callback(self, type_name: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(s: zenoh.Sample) -> None:
            self._enqueue(Sample(time.time_ns(), str(s.key_expr), s.payload.to_bytes(), type_name))
        return on_sample

    def _log_loop(self) -> None:
        while (sample := self.samples.get()) is not None:
            rr.set_time("time", timestamp=sample.t_ns / 1e9)
            try:
                if sample.type_name:
                    msg = ros2.MESSAGE_TYPES[sample.type_name].deserialize(sample.payload)
                    topic = sample.key.split("/")[1:-2]
                    LOGGERS[sample.type_name]("ros2/" + "/".join(topic), msg, self.dbc)
                elif sample.key.endswith("/rx") or sample.key.endswith("/tx"):
                    parts = sample.key[len(self.prefix) + 1:].split("/")
                    with self.lock:
                        only = next(iter(self.buses)) if len(self.buses) == 1 else "bus"
                    bus = parts[0] if len(parts) == 2 else only
                    log_can_frames(f"can/{parts[-1]}/{bus}", wire.decode_batch(sample.payload), self.dbc)
                else:
                    continue
            except Exception as e:  # noqa: BLE001 - a bad sample is shown, never fatal
                rr.log("discovery/errors", rr.TextLog(f"{sample.key}: {e}"))
            with self.lock:
                self.logged += 1

    def stop(self) -> None:
        self.token.undeclare()
        self.samples.put(None)
        self.logger.join(timeout=10)


def open_session(mode: str, endpoints: list[str]) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(endpoints or [DEFAULT_ENDPOINT]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def view_mcap(path: Path, dbc) -> int:
    """A bench recording (recording.mcap) into Rerun: bus frames and decoded signals."""
    from mcap.reader import make_reader
    count = 0
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            rr.set_time("time", timestamp=message.log_time / 1e9)
            data = json.loads(message.data)
            if channel.topic.startswith("/can/") or channel.topic.startswith("/zenoh/"):
                frame = wire.Frame(data["id"], data["dlc"], bytes.fromhex(data["data"]), data["extended"],
                                   data["remote"])
                side = "zenoh" if channel.topic.startswith("/zenoh/") else "rx"
                log_can_frames(f"can/{side}/{data['bus']}", [frame], dbc)
            elif channel.topic.startswith("/signals/"):
                for name, value in data.items():
                    _scalar(f"signals{channel.topic[len('/signals'):]}/{name}", value)
            count += 1
    return count


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run(args) -> int:
    rr.init("canbench-view", spawn=False)
    if args.save:
        rr.save(str(args.save))
    else:
        rr.spawn()
    dbc = load_dbc(args.dbc) if args.dbc else None
    if args.source:
        print(f"canbench view: {view_mcap(args.source, dbc)} messages from {args.source}")
        rr.disconnect()
        return 0
    # docker stop / compose stop: end like Ctrl-C, so the .rrd is complete; SIGINT explicitly too,
    # because a viewer started from a background job inherits SIGINT ignored and would never stop
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    session = open_session(args.zenoh_mode, args.zenoh_connect)
    viewer = Viewer(session, args.topic, args.auto_subscribe, dbc)
    viewer.start()
    try:
        deadline = time.monotonic() + args.duration if args.duration else None
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)  # the UI loop of a CLI: nothing to synchronise with
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
        session.close()
        rr.disconnect()
    with viewer.lock:
        print(f"canbench view: {len(viewer.bridges)} bridge tokens, {len(viewer.entities)} ROS 2 entities, "
              f"{len(viewer.subscribers)} subscriptions, {viewer.dropped} samples dropped (viewer too slow)")
    return 0
