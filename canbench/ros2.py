# mypy: disable-error-code="valid-type,assignment,type-arg"
# (pycdr2 declares CDR types with annotations such as array[float64, 9] that are not Python types)
"""ROS 2 over Zenoh as rmw_zenoh speaks it: liveliness tokens, data keys, type
names, RIHS01 type hashes and CDR payloads of the message types the viewer and
the bridge's ROS 2 output use.

Liveliness token (rmw_zenoh docs/design.md), '%' standing for '/':
  @ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/<enclave>/<namespace>/<node>
          [/<topic>/<dds type>/<type hash>/<qos>]
  kinds: NN node, MP publisher, MS subscription, SS service server, SC client
Data key: <domain>/<topic without outer '/'>/<dds type>/<type hash>

Type hashes follow REP-2011 (rosidl_generator_type_description): sha256 of
the type description JSON without default values; checked in the unit tests
against hashes published for std_msgs/String and sensor_msgs/Imu. CDR via
pycdr2 (Eclipse Cyclone DDS's Python CDR)."""

import hashlib
import json
from dataclasses import dataclass, field, replace

from pycdr2 import IdlStruct
from pycdr2.types import array, float64, int32, uint8, uint32

from .errors import BenchError

LIVELINESS_PREFIX = "@ros2_lv"
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


def parse_token(key: str) -> Entity:
    parts = key.split("/")
    if parts[0] != LIVELINESS_PREFIX or len(parts) not in (9, 13):
        raise TokenError(f"not an rmw_zenoh liveliness token (9 or 13 fields): {key!r}")
    if parts[5] not in KINDS:
        raise TokenError(f"unknown entity kind {parts[5]!r} in {key!r}")
    if not parts[1].isdigit():
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


# ---- type descriptions and RIHS01 hashes (REP-2011) ----

T_NESTED, T_INT32, T_UINT32, T_UINT8, T_FLOAT, T_DOUBLE, T_BOOL, T_STRING = 1, 6, 7, 3, 10, 11, 15, 17
ARRAY = 48  # fixed-size array type ids are the element's + 48


def _f(name: str, type_id: int, nested: str = "", capacity: int = 0) -> dict:
    return {"name": name, "type": {"type_id": type_id, "capacity": capacity, "string_capacity": 0,
                                   "nested_type_name": nested}}


TYPES: dict[str, list[dict]] = {
    "builtin_interfaces/msg/Time": [_f("sec", T_INT32), _f("nanosec", T_UINT32)],
    "std_msgs/msg/Header": [_f("stamp", T_NESTED, "builtin_interfaces/msg/Time"), _f("frame_id", T_STRING)],
    "std_msgs/msg/String": [_f("data", T_STRING)],
    "geometry_msgs/msg/Quaternion": [_f(n, T_DOUBLE) for n in "xyzw"],
    "geometry_msgs/msg/Vector3": [_f(n, T_DOUBLE) for n in "xyz"],
    "sensor_msgs/msg/Imu": [
        _f("header", T_NESTED, "std_msgs/msg/Header"), _f("orientation", T_NESTED, "geometry_msgs/msg/Quaternion"),
        _f("orientation_covariance", T_DOUBLE + ARRAY, capacity=9),
        _f("angular_velocity", T_NESTED, "geometry_msgs/msg/Vector3"),
        _f("angular_velocity_covariance", T_DOUBLE + ARRAY, capacity=9),
        _f("linear_acceleration", T_NESTED, "geometry_msgs/msg/Vector3"),
        _f("linear_acceleration_covariance", T_DOUBLE + ARRAY, capacity=9)],
    "sensor_msgs/msg/Temperature": [_f("header", T_NESTED, "std_msgs/msg/Header"), _f("temperature", T_DOUBLE),
                                    _f("variance", T_DOUBLE)],
    "sensor_msgs/msg/FluidPressure": [_f("header", T_NESTED, "std_msgs/msg/Header"),
                                      _f("fluid_pressure", T_DOUBLE), _f("variance", T_DOUBLE)],
    "sensor_msgs/msg/RelativeHumidity": [_f("header", T_NESTED, "std_msgs/msg/Header"),
                                         _f("relative_humidity", T_DOUBLE), _f("variance", T_DOUBLE)],
    "sensor_msgs/msg/Illuminance": [_f("header", T_NESTED, "std_msgs/msg/Header"), _f("illuminance", T_DOUBLE),
                                    _f("variance", T_DOUBLE)],
    # can_msgs (ros-drivers/ros_canopen, ROS 2): Frame.msg
    "can_msgs/msg/Frame": [_f("header", T_NESTED, "std_msgs/msg/Header"), _f("id", T_UINT32),
                           _f("is_rtr", T_BOOL), _f("is_extended", T_BOOL), _f("is_error", T_BOOL),
                           _f("dlc", T_UINT8), _f("data", T_UINT8 + ARRAY, capacity=8)],
}


def type_hash(ros_type: str) -> str:
    """RIHS01_<sha256> of the type description, as rosidl computes it."""
    refs: set[str] = set()
    queue = [f["type"]["nested_type_name"] for f in TYPES[ros_type] if f["type"]["nested_type_name"]]
    while queue:
        name = queue.pop()
        if name not in refs:
            refs.add(name)
            queue += [f["type"]["nested_type_name"] for f in TYPES[name] if f["type"]["nested_type_name"]]
    description = {"type_description": {"type_name": ros_type, "fields": TYPES[ros_type]},
                   "referenced_type_descriptions": [{"type_name": n, "fields": TYPES[n]} for n in sorted(refs)]}
    return "RIHS01_" + hashlib.sha256(json.dumps(description, separators=(", ", ": ")).encode()).hexdigest()


# ---- CDR message types (field order = the .msg files) ----

@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs/msg/Header"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class String(IdlStruct, typename="std_msgs/msg/String"):
    data: str = ""


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs/msg/Vector3"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Imu(IdlStruct, typename="sensor_msgs/msg/Imu"):
    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)


@dataclass
class Temperature(IdlStruct, typename="sensor_msgs/msg/Temperature"):
    header: Header = field(default_factory=Header)
    temperature: float64 = 0.0
    variance: float64 = 0.0


@dataclass
class FluidPressure(IdlStruct, typename="sensor_msgs/msg/FluidPressure"):
    header: Header = field(default_factory=Header)
    fluid_pressure: float64 = 0.0
    variance: float64 = 0.0


@dataclass
class RelativeHumidity(IdlStruct, typename="sensor_msgs/msg/RelativeHumidity"):
    header: Header = field(default_factory=Header)
    relative_humidity: float64 = 0.0
    variance: float64 = 0.0


@dataclass
class Illuminance(IdlStruct, typename="sensor_msgs/msg/Illuminance"):
    header: Header = field(default_factory=Header)
    illuminance: float64 = 0.0
    variance: float64 = 0.0


@dataclass
class CanFrame(IdlStruct, typename="can_msgs/msg/Frame"):
    header: Header = field(default_factory=Header)
    id: uint32 = 0
    is_rtr: bool = False
    is_extended: bool = False
    is_error: bool = False
    dlc: uint8 = 0
    data: array[uint8, 8] = field(default_factory=lambda: bytes(8))  # CDR gives uint8 arrays back as bytes


MESSAGE_TYPES: dict[str, type[IdlStruct]] = {
    cls.__idl_typename__: cls  # type: ignore[attr-defined]
    for cls in (String, Imu, Temperature, FluidPressure, RelativeHumidity, Illuminance, CanFrame)
}

