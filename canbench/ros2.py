"""ROS 2 over Zenoh as rmw_zenoh speaks it: liveliness tokens, data keys, type
names, RIHS01 type hashes and CDR payloads of the message types the viewer and
the bridge's ROS 2 output use.

Liveliness token (rmw_zenoh docs/design.md), '%' standing for '/':
  @ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/<enclave>/<namespace>/<node>
          [/<topic>/<dds type>/<type hash>/<qos>]
  kinds: NN node, MP publisher, MS subscription, SS service server, SC client
Data key: <domain>/<topic without outer '/'>/<dds type>/<type hash>
Node/Publisher: the bench's own ROS 2 publishers (tests, benchmarks) declare these
tokens and attach rmw_zenoh's per-sample attachment, as rmw_zenoh nodes do.

Type hashes follow REP-2011 (rosidl_generator_type_description): sha256 of
the type description JSON without default values; checked in the unit tests
against hashes published for std_msgs/String and sensor_msgs/Imu. The type
description is read off the CDR structs of ros2_msgs (one source for the
wire format and the hash). CDR via pycdr2 (Eclipse Cyclone DDS's Python CDR)."""

import functools
import hashlib
import json
import typing
from dataclasses import dataclass, replace

from pycdr2.types import array, sequence

from .errors import BenchError
from .ros2_msgs import MESSAGE_TYPES, CdrError, decode

__all__ = ["MESSAGE_TYPES", "CdrError", "decode"]  # re-exported: the messages live in ros2_msgs

LIVELINESS_PREFIX = "@ros2_lv"
RMW_ZENOH_DEFAULT_DEPTH = 42  # samples (rmw_zenoh_cpp/src/detail/qos.cpp): what an empty depth in a token's QoS means
KINDS = {"NN": "node", "MP": "publisher", "MS": "subscription", "SS": "service server", "SC": "service client"}


class TokenError(BenchError):
    """A liveliness token that is not in rmw_zenoh's format."""


def mangle(name: str) -> str:
    return name.replace("/", "%")


def demangle(name: str) -> str:
    return name.replace("%", "/")


def dds_type_name(ros_type: str) -> str:
    """'sensor_msgs/msg/Imu' -> 'sensor_msgs::msg::dds_::Imu_'."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> str:
    """'sensor_msgs::msg::dds_::Imu_' -> 'sensor_msgs/msg/Imu'."""
    parts = dds_type.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise TokenError(f"not a DDS type name: {dds_type!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


@dataclass(frozen=True)
class Entity:
    domain_id: int
    zid: str
    nid: str
    id: str
    kind: str          # NN, MP, MS, SS, SC
    enclave: str
    namespace: str
    node: str
    topic: str = ""    # '/chatter'
    type_name: str = ""  # 'std_msgs/msg/String'
    type_hash: str = ""
    qos: str = ""

    @property
    def data_key(self) -> str:
        return data_key(self.domain_id, self.topic, self.type_name, self.type_hash)

    @property
    def transient_local_depth(self) -> int | None:
        """The history a TRANSIENT_LOCAL publisher keeps for late subscribers (/tf_static, /map),
        None for a VOLATILE one. rmw_zenoh's QoS field: reliability:durability:history,depth:..., a
        value equal to rmw_zenoh's own default left empty (qos_to_keyexpr; durability 1 is
        TRANSIENT_LOCAL; an empty depth is its RMW_ZENOH_DEFAULT_HISTORY_DEPTH, not rmw's 10)."""
        parts = self.qos.split(":")
        if len(parts) < 3 or parts[1] != "1":
            return None
        depth = parts[2].partition(",")[2]
        return int(depth) if depth.isascii() and depth.isdigit() and int(depth) > 0 else RMW_ZENOH_DEFAULT_DEPTH


def parse_token(key: str) -> Entity:
    parts = key.split("/")
    if parts[0] != LIVELINESS_PREFIX or len(parts) not in (9, 13):
        raise TokenError(f"not an rmw_zenoh liveliness token (9 or 13 fields): {key!r}")
    if parts[5] not in KINDS:
        raise TokenError(f"unknown entity kind {parts[5]!r} in {key!r}")
    if not (parts[1].isascii() and parts[1].isdigit()):  # isdigit alone takes '²', which int() refuses
        raise TokenError(f"domain id {parts[1]!r} is not a number in {key!r}")
    node = Entity(int(parts[1]), parts[2], parts[3], parts[4], parts[5], demangle(parts[6]), demangle(parts[7]),
                  parts[8])
    if len(parts) == 9:
        return node
    return replace(node, topic=demangle(parts[9]), type_name=ros_type_name(parts[10]), type_hash=parts[11],
                   qos=parts[12])


def data_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def publisher_token(domain_id: int, zid: str, nid: int, eid: int, namespace: str, node: str, topic: str,
                    ros_type: str, type_hash: str, qos: str = "::,10:,:,:,,") -> str:
    return "/".join([LIVELINESS_PREFIX, str(domain_id), zid, str(nid), str(eid), "MP", "%",
                     mangle(namespace or "/"), node, mangle(topic), dds_type_name(ros_type), type_hash, qos])


def node_token(domain_id: int, zid: str, nid: int, namespace: str, node: str) -> str:
    return "/".join([LIVELINESS_PREFIX, str(domain_id), zid, str(nid), str(nid), "NN", "%",
                     mangle(namespace or "/"), node])


# ---- a node as rmw_zenoh runs one (the bench's own ROS 2 publishers: tests, benchmarks) ----

def attachment(sequence: int, source_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's per-sample attachment: int64 sequence number, int64 source timestamp,
    the publisher's 16-byte GID, in Zenoh's serialization (z_serialize)."""
    from zenoh.ext import Int64, z_serialize
    return z_serialize((Int64(sequence), Int64(source_ns), gid)).to_bytes()


class Publisher:
    def __init__(self, node: "Node", eid: int, topic: str, ros_type: str, transient_local: int = 0):
        """transient_local: the depth a TRANSIENT_LOCAL publisher keeps for late subscribers, as
        rmw_zenoh keeps it (an AdvancedPublisher's cache, publisher detection on); 0: VOLATILE."""
        self.session, self.topic, self.ros_type = node.session, topic, ros_type
        self.type_hash = type_hash(ros_type)
        self.key = data_key(node.domain_id, topic, ros_type, self.type_hash)
        token = publisher_token(node.domain_id, node.zid, node.nid, eid, node.namespace, node.name, topic, ros_type,
                                self.type_hash, f":1:,{transient_local}:,:,:,," if transient_local else "::,10:,:,:,,")
        self.token_key = token
        self.gid = hashlib.sha256(token.encode()).digest()[:16]
        if transient_local:
            import zenoh.ext
            self.publisher = zenoh.ext.declare_advanced_publisher(
                self.session, self.key, congestion_control=node.congestion_control,
                cache=zenoh.ext.CacheConfig(transient_local), publisher_detection=True)
        else:
            self.publisher = self.session.declare_publisher(self.key, congestion_control=node.congestion_control)
        self.token = self.session.liveliness().declare_token(token)  # after the publisher: ready when seen
        self.sequence = 0

    def put(self, payload) -> None:
        """A message (a ros2_msgs struct) or raw CDR bytes (tests send malformed ones)."""
        import time
        self.sequence += 1
        data = payload if isinstance(payload, bytes) else payload.serialize()
        self.publisher.put(data, attachment=attachment(self.sequence, time.time_ns(), self.gid))

    def undeclare(self) -> None:
        if self.token is not None:
            self.token.undeclare()
            self.publisher.undeclare()
            self.token = None


class Node:
    """Liveliness tokens, data keys and attachments as rmw_zenoh declares them, on a Zenoh session."""

    def __init__(self, session, name: str, namespace: str = "/", domain_id: int = 0, nid: int = 0):
        import zenoh
        self.session, self.name, self.namespace, self.domain_id, self.nid = session, name, namespace, domain_id, nid
        self.zid = str(session.info.zid())
        self.congestion_control = zenoh.CongestionControl.BLOCK  # a test publisher loses nothing
        self.token = session.liveliness().declare_token(node_token(domain_id, self.zid, nid, namespace, name))
        self.publishers: list[Publisher] = []

    def publisher(self, topic: str, ros_type: str, transient_local: int = 0) -> Publisher:
        pub = Publisher(self, self.nid + 1 + len(self.publishers), topic, ros_type, transient_local)
        self.publishers.append(pub)
        return pub

    def close(self) -> None:
        for pub in self.publishers:
            pub.undeclare()
        self.token.undeclare()


# ---- type descriptions and RIHS01 hashes (REP-2011) ----

# rosidl's FieldType ids (type_description_interfaces/msg/FieldType.msg)
T_NESTED = 1
PRIMITIVES = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8, "uint64": 9,
              "float32": 10, "float64": 11, "char": 13, bool: 15, "byte": 16, str: 17}
# .msg fields of type byte: one octet on the wire as a uint8 (how ros2_msgs declares them), but
# byte to the type hash and the .msg text
BYTE_FIELDS = {("diagnostic_msgs/msg/DiagnosticStatus", "level")}
ARRAY, BOUNDED_SEQUENCE, SEQUENCE = 48, 96, 144  # added to the element's id


def _element(annotation) -> tuple[int, str]:
    """(type id, nested type name) of a scalar annotation of a ros2_msgs struct."""
    if isinstance(annotation, type) and hasattr(annotation, "__idl_typename__"):
        return T_NESTED, annotation.__idl_typename__
    key = annotation.__metadata__[0] if hasattr(annotation, "__metadata__") else annotation
    return PRIMITIVES[key], ""


def fields(ros_type: str, cls=None) -> list[dict]:
    """The type description's fields of a type (of cls, another definition of it, when given)."""
    out = []
    for name, annotation in typing.get_type_hints(cls or MESSAGE_TYPES[ros_type], include_extras=True).items():
        meta = getattr(annotation, "__metadata__", (None,))[0]
        capacity = 0
        if isinstance(meta, array):
            (type_id, nested), capacity = _element(meta.subtype), meta.length
            type_id += ARRAY
        elif isinstance(meta, sequence):
            (type_id, nested), capacity = _element(meta.subtype), meta.max_length or 0
            type_id += BOUNDED_SEQUENCE if capacity else SEQUENCE
        elif (ros_type, name) in BYTE_FIELDS:
            type_id, nested = PRIMITIVES["byte"], ""
        else:
            type_id, nested = _element(annotation)
        out.append({"name": name, "type": {"type_id": type_id, "capacity": capacity, "string_capacity": 0,
                                           "nested_type_name": nested}})
    return out


def same_definition(entity: Entity) -> bool:
    """Whether a publisher's type is the definition ros2_msgs decodes: its token's RIHS01 hash is
    ours (a same-named type of another definition decodes as garbage); a token without a hash
    (Humble's TypeHashNotSupported) cannot say otherwise."""
    return not entity.type_hash.startswith("RIHS01_") or entity.type_hash == type_hash(entity.type_name)


@functools.cache
def type_hash(ros_type: str) -> str:
    """RIHS01_<sha256> of the type description, as rosidl computes it."""
    refs: set[str] = set()
    queue = [f["type"]["nested_type_name"] for f in fields(ros_type) if f["type"]["nested_type_name"]]
    while queue:
        name = queue.pop()
        if name not in refs:
            refs.add(name)
            queue += [f["type"]["nested_type_name"] for f in fields(name) if f["type"]["nested_type_name"]]
    description = {"type_description": {"type_name": ros_type, "fields": fields(ros_type)},
                   "referenced_type_descriptions": [{"type_name": n, "fields": fields(n)} for n in sorted(refs)]}
    return "RIHS01_" + hashlib.sha256(json.dumps(description, separators=(", ", ": ")).encode()).hexdigest()


# ---- .msg text (MCAP's ros2msg schema encoding) ----

MSG_PRIMITIVES = {v: k for k, v in PRIMITIVES.items() if isinstance(k, str)} | {15: "bool", 17: "string"}


def _msg_field(f: dict) -> str:
    t = f["type"]
    base, capacity = t["type_id"] % ARRAY, t["capacity"]
    kind = t["type_id"] // ARRAY  # 0 scalar, 1 array, 2 bounded sequence, 3 sequence
    nested = t["nested_type_name"].replace("/msg/", "/")
    name = nested if base == T_NESTED else MSG_PRIMITIVES[base]
    suffix = ["", f"[{capacity}]", f"[<={capacity}]", "[]"][kind]
    return f"{name}{suffix} {f['name']}"


def msg_definition(ros_type: str, cls=None) -> str:
    """The type's .msg text with its nested types appended, as ROS 2 bags (and so MCAP's
    ros2msg schemas) carry it: '=' * 80, then 'MSG: pkg/Type' and its fields, per type
    (cls: another definition of the type, its nested types ours)."""
    order, queue = [], [ros_type]
    while queue:
        name = queue.pop(0)
        if name not in order:
            order.append(name)
            queue += [f["type"]["nested_type_name"] for f in fields(name, cls if name == ros_type else None)
                      if f["type"]["nested_type_name"]]
    parts = ["\n".join(_msg_field(f) for f in fields(order[0], cls))]
    for name in order[1:]:
        body = "\n".join(_msg_field(f) for f in fields(name))
        parts.append(f"{'=' * 80}\nMSG: {name.replace('/msg/', '/')}\n{body}")
    return "\n".join(parts) + "\n"


# ---- a recording's definitions (an MCAP's ros2msg schemas) against ours ----

# the .msg primitive types (a bounded string is string<=N)
MSG_BUILTINS = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                "int64", "uint64", "string", "wstring"}
SECTION_RULE = "=" * 80


def _msg_type(written: str, package: str) -> str:
    """A field's type as msg_definition writes it: primitives as they are, a nested type as
    pkg/Type (a .msg names its own package's types without it; ROS 1's Header is std_msgs')."""
    base, bracket, suffix = written.partition("[")
    if base.split("<=")[0] in MSG_BUILTINS:
        return written
    parts = base.split("/")
    if len(parts) == 1:
        base = "std_msgs/Header" if base == "Header" else f"{package}/{base}"
    else:
        base = f"{parts[0]}/{parts[-1]}"
    return base + bracket + suffix


def msg_fields(type_name: str, text: str) -> dict[str, list[tuple[str, str]]]:
    """pkg/Type -> [(type, name)] of each section of a ros2msg schema (the type's .msg text, then
    '=' * 80 and 'MSG: pkg/Type' per nested type); comments, constants and default values left out."""
    sections: dict[str, list[tuple[str, str]]] = {}
    current = type_name.replace("/msg/", "/")
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or line == SECTION_RULE:
            continue
        if line.startswith("MSG:"):
            current = line[4:].strip().replace("/msg/", "/")
            continue
        written, _, rest = line.partition(" ")
        rest = rest.strip()
        words = rest.split("=", 1)[0].split()
        name = words[0] if words else ""
        if not name or rest[len(name):].lstrip().startswith("="):
            continue  # a constant (TYPE NAME=VALUE) or a line that is no field
        sections.setdefault(current, []).append((_msg_type(written, current.split("/")[0]), name))
    return sections


def definition_difference(type_name: str, schema_text: str, cls=None) -> str | None:
    """How a recording's definition of a type (its MCAP schema) differs from the one ros2_msgs
    decodes (cls: another of ours, HUMBLE_VARIANTS'), in the first type of it that differs; None
    when they agree. A nested type the schema does not carry cannot be compared and is taken as ours."""
    ours = msg_fields(type_name, msg_definition(type_name, cls))
    theirs = msg_fields(type_name, schema_text)
    for name, fields in ours.items():
        recorded = theirs.get(name)
        if recorded is None and name != type_name.replace("/msg/", "/"):
            continue
        if recorded != fields:
            recorded = recorded or []
            pairs = zip(recorded, fields, strict=False)  # up to the shorter: the rest is a count apart
            i = next((i for i, (a, b) in enumerate(pairs) if a != b), min(len(recorded), len(fields)))
            said = (f"field {i + 1} is '{' '.join(recorded[i])}' there, '{' '.join(fields[i])}' here"
                    if i < len(recorded) and i < len(fields) else
                    f"{len(recorded)} fields there, {len(fields)} here")
            return f"{name}: {said}"
    return None
