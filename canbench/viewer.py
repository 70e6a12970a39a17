"""canbench view: see what is on a Zenoh network in Rerun.

Discovers, live, by liveliness tokens: the bridges (vehicle/can/bridges/<name>/
<bus>/<mode>) and ROS 2 entities (rmw_zenoh's @ros2_lv/*/**, or one domain's
@ros2_lv/<N>/**: a hermetic prefix that wildcards never match, so it is asked
for explicitly). Subscribes to the
bridges' CAN keys and to the selected ROS 2 topics (-t, or every supported one
with --auto-subscribe), one subscriber per data key, dropped again when the
last publisher's token goes away. Callbacks only enqueue; one thread decodes
(canbench.ros2_msgs) and logs (canbench.viewer_types.LOGGERS). A malformed
payload is counted per topic and skipped; an unsupported type is listed once.

  canbench view --zenoh-connect tcp/127.0.0.1:7447 --auto-subscribe [--dbc f.dbc] [--bus-dbc BUS=f.dbc ...]
                [--urdf car.urdf] [--save out.rrd]
  canbench view reports/latest/recording.mcap

Network safety: multicast scouting is off; endpoints are explicit."""
from __future__ import annotations

import json
import os
import queue
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import rerun as rr
import zenoh

from . import ros2, ros2_msgs, runkeys, wire
from .dbc import read_dbc
from .errors import InputError
from .viewer_args import DEFAULT_ENDPOINT
from .viewer_spawn import spawn_local_viewer
from .viewer_types import LOGGERS, Context
from .viewer_types.can import CanColumns
from .viewer_types.markers import expire
from .viewer_types.registry import ScalarColumns, set_sample_time

QUEUE_SAMPLES = 100_000  # samples between the network callbacks and the logger thread
QUEUE_BYTES = 512 << 20  # and their payloads' bytes: behind a camera's 6 MB frames the count alone held gigabytes
BATCH_SAMPLES = 2_000    # the logger drains up to this many samples at a time
ERRORS_SHOWN = 10        # malformed samples described per topic; the rest are only counted
IDLE_TICK_S = 0.5        # with no samples, the logger still clears markers whose lifetime ended


@dataclass
class Sample:
    t_ns: int
    key: str
    payload: bytes
    type_name: str = ""  # ROS 2 type for data keys; "" for the bridge's CAN keys


def read_rrd_columns(path: Path) -> dict[str, dict[str, list]]:
    """entity path -> 'Archetype:component' -> the values logged there, in order, read back
    with Rerun's own reader (one value per row; a row of a batch archetype is a list)."""
    from rerun.chunk import RrdReader
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        columns = out.setdefault(str(chunk.entity_path), {})
        for name in batch.schema.names:
            if ":" in name:
                columns.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def read_rrd(path: Path) -> dict[str, list]:
    """entity path -> the scalars or texts logged there: what tests and nightly scripts check."""
    out: dict[str, list] = {}
    for entity, columns in read_rrd_columns(path).items():
        for column in ("Scalars:scalars", "TextLog:text"):
            if column in columns:
                out.setdefault(entity, []).extend(v[0] for v in columns[column])
    return out


def normalise_topic(topic: str) -> str:
    return "/" + topic.strip("/")


# ---- live viewer ----

class Viewer:
    def __init__(self, session: zenoh.Session, topics: list[str], auto_subscribe: bool, dbc=None,
                 prefix: str = "vehicle/can", bus_dbcs: dict | None = None, domain: int | None = None):
        """domain: the ROS_DOMAIN_ID whose entities it discovers, as an rmw_zenoh node watches its own
        (None: every domain, each at its own path)."""
        self.session, self.auto, self.prefix, self.domain = session, auto_subscribe, prefix, domain
        self.topics = {normalise_topic(t) for t in topics}
        self.ctx = Context(dbc, bus_dbcs)  # a bus's own DBC, by the bus its keys name; else dbc
        self.scalars = self.ctx.scalars = ScalarColumns()  # sent per entity when due
        self.can = self.ctx.can = CanColumns(dbc, self.ctx.bus_dbcs)  # the bridge's frames and can_msgs' alike
        self.samples: queue.Queue[Sample | None] = queue.Queue(maxsize=QUEUE_SAMPLES)
        self.entities: dict[str, ros2.Entity] = {}
        self.bridges: set[str] = set()
        self.subscribers: dict[str, object] = {}
        self.publishers: dict[str, set[str]] = {}  # ROS 2 data key -> tokens of its live publishers
        self.asks_caches: set[str] = set()  # data keys whose subscriber asks TRANSIENT_LOCAL publishers' caches
        self.unsupported: set[str] = set()
        self.malformed: Counter[str] = Counter()
        self.dropped = 0
        self.queued_bytes = 0  # payload bytes in self.samples (QUEUE_BYTES)
        self.queue_lock = threading.Lock()
        self.logged = 0
        self.buses: set[str] = set()
        self.lock = threading.Lock()

    def _enqueue(self, sample: Sample) -> None:
        with self.queue_lock:  # the network's callback threads (never self.lock: a callback may run under it)
            if self.queued_bytes + len(sample.payload) > QUEUE_BYTES:
                self.dropped += 1  # a viewer never slows the network down; counted
                return
            try:
                self.samples.put_nowait(sample)
            except queue.Full:
                self.dropped += 1
                return
            self.queued_bytes += len(sample.payload)

    def start(self) -> None:
        self.logger = threading.Thread(target=self._log_loop, daemon=True, name="loggers")
        self.logger.start()
        key = f"{self.prefix}/**"
        self.subscribers[key] = self.session.declare_subscriber(
            key, lambda s: self._enqueue(Sample(time.time_ns(), str(s.key_expr), s.payload.to_bytes())))
        self.lv_bridges = self.session.liveliness().declare_subscriber(
            f"{self.prefix}/bridges/**", self._on_bridge_token, history=True)
        self.lv_ros = self.session.liveliness().declare_subscriber(
            f"{ros2.LIVELINESS_PREFIX}/{'*' if self.domain is None else self.domain}/**", self._on_ros_token,
            history=True)
        # after the subscribers: whoever sees this token knows they are in place; the
        # queryable answers how much was logged (tests and scripts wait on it, never sleep)
        me = f"canbench/viewers/{self.session.info.zid()}"
        self.stats_queryable = self.session.declare_queryable(f"{me}/stats", self._on_stats_query)
        self.token = self.session.liveliness().declare_token(me)

    def stats(self) -> dict:
        with self.lock:
            return {"logged": self.logged, "dropped": self.dropped, "bridges": sorted(self.bridges),
                    "ros2_entities": len(self.entities), "subscriptions": sorted(self.subscribers),
                    "malformed": dict(self.malformed), "unsupported": sorted(self.unsupported)}

    def _on_stats_query(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, json.dumps(self.stats()))

    def _on_bridge_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        alive = sample.kind == zenoh.SampleKind.PUT
        with self.lock:
            (self.bridges.add if alive else self.bridges.discard)(key)
            # vehicle/can/bridges/<name>/<bus>/<mode>: the bus a single-bus bridge's keys stand for
            self.buses = {k.split("/")[-2] for k in self.bridges}
        rr.log("discovery/bridges", rr.TextLog(f"{'+' if alive else '-'} {key}"))

    def wanted(self, entity: ros2.Entity) -> bool:
        return entity.kind == "MP" and self.decodable(entity) and (self.auto or entity.topic in self.topics)

    @staticmethod
    def decodable(entity: ros2.Entity) -> bool:
        """A type with a logger, of the definition the viewer decodes (its token's hash)."""
        return entity.type_name in LOGGERS and ros2.same_definition(entity)

    def _on_ros_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            entity = ros2.parse_token(key)
        except ros2.TokenError as e:
            rr.log("discovery/ros2", rr.TextLog(f"unparsable token: {e}"))
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        supported = self.decodable(entity)
        why = "no logger" if entity.type_name not in LOGGERS else "another definition: its hash is not the viewer's"
        rr.log("discovery/ros2", rr.TextLog(
            f"{'+' if alive else '-'} {ros2.KINDS[entity.kind]} {entity.namespace.rstrip('/')}/{entity.node} "
            f"{entity.topic} [{entity.type_name or '-'}]" + ("" if supported or not entity.topic else f" ({why})")))
        with self.lock:
            if alive:
                self.entities[key] = entity
            else:
                self.entities.pop(key, None)
            shown = entity.type_name if entity.type_name not in LOGGERS else f"{entity.type_name} {entity.type_hash}"
            if entity.topic and not supported and shown not in self.unsupported:
                self.unsupported.add(shown)  # listed once, however many topics carry it
                rr.log("discovery/unsupported", rr.TextLog(
                    f"{shown} (first seen on {entity.topic}{'' if entity.type_name not in LOGGERS else ': ' + why})"))
            if not self.wanted(entity):
                return
            publishers = self.publishers.setdefault(entity.data_key, set())
            (publishers.add if alive else publishers.discard)(key)
            if publishers and entity.data_key not in self.subscribers:
                self.subscribers[entity.data_key] = self._subscribe(entity)
                rr.log("discovery/subscriptions", rr.TextLog(f"+ {entity.topic} [{entity.type_name}]"))
            elif (alive and entity.transient_local_depth is not None and entity.data_key in self.subscribers
                  and entity.data_key not in self.asks_caches):
                # a TRANSIENT_LOCAL publisher after VOLATILE ones on the key: a subscriber that asks its cache
                self.subscribers.pop(entity.data_key).undeclare()  # type: ignore[attr-defined]
                self.subscribers[entity.data_key] = self._subscribe(entity)
            elif not publishers and entity.data_key in self.subscribers:
                self.subscribers.pop(entity.data_key).undeclare()  # type: ignore[attr-defined]
                self.asks_caches.discard(entity.data_key)
                del self.publishers[entity.data_key]
                rr.log("discovery/subscriptions", rr.TextLog(f"- {entity.topic} [{entity.type_name}]"))

    def _subscribe(self, entity: ros2.Entity):
        """A subscriber to a topic's data key; for a TRANSIENT_LOCAL publisher one that also asks the
        publishers' caches (as rmw_zenoh's subscribers do): /tf_static and /map, published once
        before the viewer started, arrive too."""
        depth = entity.transient_local_depth
        if depth is None:
            return self.session.declare_subscriber(entity.data_key, self._ros_callback(entity.type_name))
        self.asks_caches.add(entity.data_key)
        import zenoh.ext
        return zenoh.ext.declare_advanced_subscriber(
            self.session, entity.data_key, self._ros_callback(entity.type_name),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=depth))

    def _ros_callback(self, type_name: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(s: zenoh.Sample) -> None:
            self._enqueue(Sample(time.time_ns(), str(s.key_expr), s.payload.to_bytes(), type_name))
        return on_sample

    def _batch(self) -> list[Sample]:
        """The next samples: waits up to IDLE_TICK_S for one (else none), then takes what is
        already queued; None ends the loop."""
        try:
            batch = [self.samples.get(timeout=IDLE_TICK_S)]
        except queue.Empty:
            return []
        while batch[-1] is not None and len(batch) < BATCH_SAMPLES:
            try:
                batch.append(self.samples.get_nowait())
            except queue.Empty:
                break
        if batch[-1] is None:
            self.stopping = True
            batch.pop()
        with self.queue_lock:
            self.queued_bytes -= sum(len(sample.payload) for sample in batch if sample is not None)
        return batch  # type: ignore[return-value]

    def _malformed(self, topic: str, error: Exception) -> None:
        with self.lock:
            self.malformed[topic] += 1
            count = self.malformed[topic]
        if count <= ERRORS_SHOWN:
            rr.log("discovery/errors", rr.TextLog(f"{topic}: {error}" + (" (further ones only counted)"
                                                                         if count == ERRORS_SHOWN else "")))

    def _log_ros(self, sample: Sample) -> None:
        domain, *names = sample.key.split("/")[:-2]
        # domain 0 (ROS's default) at ros2/<topic>, another at ros2/domain<N>/<topic>: same-named
        # topics of two domains are two robots, never one entity
        topic = ("" if domain == "0" else f"/domain{domain}") + "/" + "/".join(names)
        try:
            humble = sample.key.endswith("/" + ros2_msgs.HUMBLE_HASH)  # Humble's rmw_zenoh: its definitions
            msg = ros2_msgs.decode(sample.type_name, sample.payload, humble)
            self.ctx.stamp_ns = set_sample_time(sample.t_ns, msg)
            self.ctx.static, self.ctx.t_ns = names == ["tf_static"], sample.t_ns
            self.ctx.domain = "" if domain == "0" else f"domain{domain}"  # its own TF tree
            LOGGERS[sample.type_name](self.ctx, "ros2" + topic, msg)
        except Exception as e:  # noqa: BLE001 - a payload, whatever it holds, never stops the viewer
            self._malformed(topic, e)

    def _log_loop(self) -> None:
        self.stopping = False
        while not self.stopping:
            batch = self._batch()
            for sample in batch:
                if sample.type_name:
                    self._log_ros(sample)
                elif sample.key.endswith("/rx") or sample.key.endswith("/tx"):
                    parts = sample.key[len(self.prefix) + 1:].split("/")
                    with self.lock:
                        only = next(iter(self.buses)) if len(self.buses) == 1 else "bus"
                    bus = parts[0] if len(parts) == 2 else only
                    try:
                        self.can.add(f"can/{parts[-1]}/{bus}", sample.t_ns, wire.decode_batch(sample.payload))
                    except ValueError as e:  # WireError
                        self._malformed(sample.key, e)
            for columns in (self.can, self.scalars):
                if columns.due() or self.stopping:
                    columns.flush()
            # markers' lifetimes: up to the newest sample logged (older ones may still be queued)
            expire(self.ctx, batch[-1].t_ns if batch else time.time_ns())
            with self.lock:
                self.logged += len(batch)
        expire(self.ctx)

    def stop(self) -> None:
        self.token.undeclare()
        self.samples.put(None)
        self.logger.join(timeout=30)


def open_session(mode: str, endpoints: list[str]) -> zenoh.Session:
    conf = runkeys.base_config()  # $ZENOH_CONFIG: TLS and identity (docs/access-control.md)
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(endpoints or [DEFAULT_ENDPOINT]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if not os.environ.get("ZENOH_CONFIG"):  # a peer listens nowhere unless the user's config says where
        conf.insert_json5("listen/endpoints", "[]")  # (Zenoh's default: every interface)
    return zenoh.open(conf)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def bus_dbc_paths(specs: list[str]) -> dict[str, Path]:
    """--bus-dbc BUS=FILE (repeatable) -> bus -> DBC path; a malformed spec, a bus named twice
    or a missing file is an InputError naming it."""
    out: dict[str, Path] = {}
    for spec in specs:
        bus, sep, path = spec.partition("=")
        if not sep or not bus or not path or "/" in bus:
            raise InputError(spec, None, "--bus-dbc: expected BUS=FILE (e.g. vcan1=body.dbc)")
        if bus in out:
            raise InputError(spec, None, f"--bus-dbc: bus {bus} given twice")
        if not Path(path).is_file():
            raise InputError(path, None, f"--bus-dbc {bus}: no such file")
        out[bus] = Path(path)
    return out


def run(args) -> int:
    for option, path in (("--urdf", args.urdf), ("--dbc", args.dbc), ("source", args.source)):
        if path is not None and not Path(path).is_file():
            raise InputError(str(path), None, f"{option}: no such file")
    bus_dbcs = {bus: read_dbc(path, args.dbc_lenient) for bus, path in bus_dbc_paths(args.bus_dbc).items()}
    dbc = read_dbc(args.dbc, args.dbc_lenient) if args.dbc else None  # refused before a viewer opens
    rr.init("canbench-view", spawn=False)
    if args.save:
        rr.save(str(args.save))
    else:
        spawn_local_viewer()  # on loopback, no usage data (canbench.viewer_spawn)
    rr.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # ROS's axes (REP 103): x forward, z up
    if args.urdf:
        # Rerun's URDF importer: links become coordinate frames named as in the URDF, joints
        # transforms between them, so TF frames of the same names attach live data to the model
        rr.log_file_from_path(args.urdf, static=True)
    if args.source:
        from .recording import view_mcap
        viewed = view_mcap(args.source, Context(dbc, bus_dbcs))
        print(f"canbench view: {viewed.logged} messages from {args.source}, {viewed.malformed} malformed, "
              f"{viewed.other_definition} not decoded (recorded with another definition of their type: "
              "discovery/errors says which)")
        rr.disconnect()
        if viewed.cut:
            print(f"canbench view: {args.source}: INCOMPLETE: the recording is cut or damaged ({viewed.cut}); "
                  "shown up to there", file=sys.stderr)
            return 1  # shown, but a script must not take it for the whole recording
        return 0
    # docker stop / compose stop: end like Ctrl-C, so the .rrd is complete; SIGINT explicitly too,
    # because a viewer started from a background job inherits SIGINT ignored and would never stop
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGINT, _interrupt)
    session = open_session(args.zenoh_mode, args.zenoh_connect)
    viewer = Viewer(session, args.topic, args.auto_subscribe, dbc, bus_dbcs=bus_dbcs, domain=args.ros_domain)
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
    s = viewer.stats()
    print(f"canbench view: {len(s['bridges'])} bridge tokens, {s['ros2_entities']} ROS 2 entities, "
          f"{len(s['subscriptions'])} subscriptions, {s['logged']} samples logged, {s['dropped']} dropped "
          f"(viewer too slow), {sum(s['malformed'].values())} malformed, unsupported types: "
          f"{', '.join(s['unsupported']) or 'none'}")
    return 0
