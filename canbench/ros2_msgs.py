# mypy: disable-error-code="valid-type,assignment,type-arg"
# (pycdr2 declares CDR types with annotations such as array[float64, 9] that are not Python types)
"""ROS 2 message types as CDR structs (pycdr2), field for field the .msg files of
ros2/common_interfaces (std_msgs, geometry_msgs, sensor_msgs, nav_msgs, diagnostic_msgs,
visualization_msgs), ros2/geometry2 (tf2_msgs), ros2/rcl_interfaces
(builtin_interfaces) and ros-drivers/ros_canopen (can_msgs). Order and types
are the wire format and, through ros2.type_hash, the RIHS01 hash: change
neither without the .msg file. decode() is the one entry for untrusted
payloads: it checks the encapsulation header before pycdr2 reads anything."""

import typing
from array import array as array_of  # (pycdr2's types name array)
from dataclasses import dataclass, field

from pycdr2 import IdlStruct
from pycdr2._machinery import PlainCdrV2SequenceOfPrimitiveMachine, StringMachine
from pycdr2.types import array, float32, float64, int8, int16, int32, int64, sequence, uint8, uint16, uint32, uint64

from .errors import BenchError


def _string_as_rclpy_reads_it(self, buffer) -> str:
    """A CDR string, bytes that are not UTF-8 replaced as rclpy decodes them (C++ nodes send any
    bytes): pycdr2's strict decode refused the whole message for one byte (a sensor's '°' in Latin-1)."""
    buffer.align(4)
    length = buffer.read("I", 4)
    text = buffer.read_bytes(length - 1)
    buffer.read("b", 1)
    return text.decode("utf-8", "replace")


StringMachine.deserialize = _string_as_rclpy_reads_it

_read_primitive_sequence = PlainCdrV2SequenceOfPrimitiveMachine.deserialize
_write_primitive_sequence = PlainCdrV2SequenceOfPrimitiveMachine.serialize


def _bytes_in_one_slice(self, buffer):
    """A uint8 sequence (an image's, a cloud's data) as bytes, an int8 one (a map's cells) as an
    array('b'), read as one slice: pycdr2 built a list of ints, 0.27 s to decode and array a 1080p
    rgb8 frame (the viewer kept up with 4 a second), about 2 s a 4000 x 4000 map. A length past the
    payload is an error, as pycdr2's element-wise read made it."""
    if self.code not in ("B", "b"):
        return _read_primitive_sequence(self, buffer)
    buffer.align(4)
    length = buffer.read("I", 4)
    data = buffer.read_bytes(length)
    if len(data) != length:
        raise ValueError(f"a sequence of {length} bytes ends past the payload")
    return data if self.code == "B" else array_of("b", data)


def _bytes_written_whole(self, buffer, value, for_key=False):
    """A uint8 or int8 sequence given as bytes or any buffer (a numpy array, an array('b')) written
    in one piece; its length the buffer's bytes (a memoryview's len counts rows or wider items)."""
    if self.code not in ("B", "b") or isinstance(value, (list, tuple)):
        return _write_primitive_sequence(self, buffer, value, for_key)
    data = value if isinstance(value, bytes) else memoryview(value).tobytes()
    if self.max_length is not None and len(data) > self.max_length:
        raise ValueError(f"a sequence of {len(data)} bytes is longer than its bound {self.max_length}")
    buffer.align(4)
    buffer.write("I", 4, len(data))
    buffer.write_bytes(data)
    return None


PlainCdrV2SequenceOfPrimitiveMachine.deserialize = _bytes_in_one_slice
PlainCdrV2SequenceOfPrimitiveMachine.serialize = _bytes_written_whole


class CdrError(BenchError):
    """A payload that is not a CDR message of the type its key announces."""


def _zeros(n: int):  # (no "from __future__ import annotations": pycdr2 reads the annotations as types)
    return field(default_factory=lambda: [0.0] * n)


def _list():
    return field(default_factory=list)


def _bytes():  # a uint8 sequence decodes as bytes (_bytes_in_one_slice): its default is too
    return field(default_factory=bytes)


def _signed_bytes():  # an int8 sequence decodes as an array('b'): its default is too
    return field(default_factory=lambda: array_of("b"))


# ---- builtin_interfaces, std_msgs ----

@dataclass
class Time(IdlStruct, typename="builtin_interfaces/msg/Time"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces/msg/Duration"):
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
class Float64(IdlStruct, typename="std_msgs/msg/Float64"):
    data: float64 = 0.0


@dataclass
class Bool(IdlStruct, typename="std_msgs/msg/Bool"):
    data: bool = False


@dataclass
class Int8(IdlStruct, typename="std_msgs/msg/Int8"):
    data: int8 = 0


@dataclass
class Int16(IdlStruct, typename="std_msgs/msg/Int16"):
    data: int16 = 0


@dataclass
class Int32(IdlStruct, typename="std_msgs/msg/Int32"):
    data: int32 = 0


@dataclass
class Int64(IdlStruct, typename="std_msgs/msg/Int64"):
    data: int64 = 0


@dataclass
class UInt8(IdlStruct, typename="std_msgs/msg/UInt8"):
    data: uint8 = 0


@dataclass
class UInt16(IdlStruct, typename="std_msgs/msg/UInt16"):
    data: uint16 = 0


@dataclass
class UInt32(IdlStruct, typename="std_msgs/msg/UInt32"):
    data: uint32 = 0


@dataclass
class UInt64(IdlStruct, typename="std_msgs/msg/UInt64"):
    data: uint64 = 0


@dataclass
class Float32(IdlStruct, typename="std_msgs/msg/Float32"):
    data: float32 = 0.0


@dataclass
class ColorRGBA(IdlStruct, typename="std_msgs/msg/ColorRGBA"):
    r: float32 = 0.0
    g: float32 = 0.0
    b: float32 = 0.0
    a: float32 = 0.0


# ---- geometry_msgs ----

@dataclass
class Vector3(IdlStruct, typename="geometry_msgs/msg/Vector3"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs/msg/Point"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs/msg/Quaternion"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs/msg/Pose"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs/msg/PoseStamped"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs/msg/PoseWithCovariance"):
    pose: Pose = field(default_factory=Pose)
    covariance: array[float64, 36] = _zeros(36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs/msg/Twist"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs/msg/TwistWithCovariance"):
    twist: Twist = field(default_factory=Twist)
    covariance: array[float64, 36] = _zeros(36)


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs/msg/TwistStamped"):
    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass
class Accel(IdlStruct, typename="geometry_msgs/msg/Accel"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class AccelStamped(IdlStruct, typename="geometry_msgs/msg/AccelStamped"):
    header: Header = field(default_factory=Header)
    accel: Accel = field(default_factory=Accel)


@dataclass
class Vector3Stamped(IdlStruct, typename="geometry_msgs/msg/Vector3Stamped"):
    header: Header = field(default_factory=Header)
    vector: Vector3 = field(default_factory=Vector3)


@dataclass
class PointStamped(IdlStruct, typename="geometry_msgs/msg/PointStamped"):
    header: Header = field(default_factory=Header)
    point: Point = field(default_factory=Point)


@dataclass
class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs/msg/PoseWithCovarianceStamped"):
    header: Header = field(default_factory=Header)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@dataclass
class PoseArray(IdlStruct, typename="geometry_msgs/msg/PoseArray"):
    header: Header = field(default_factory=Header)
    poses: sequence[Pose] = _list()


@dataclass
class TwistWithCovarianceStamped(IdlStruct, typename="geometry_msgs/msg/TwistWithCovarianceStamped"):
    header: Header = field(default_factory=Header)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class AccelWithCovariance(IdlStruct, typename="geometry_msgs/msg/AccelWithCovariance"):
    accel: Accel = field(default_factory=Accel)
    covariance: array[float64, 36] = _zeros(36)


@dataclass
class AccelWithCovarianceStamped(IdlStruct, typename="geometry_msgs/msg/AccelWithCovarianceStamped"):
    header: Header = field(default_factory=Header)
    accel: AccelWithCovariance = field(default_factory=AccelWithCovariance)


@dataclass
class Wrench(IdlStruct, typename="geometry_msgs/msg/Wrench"):
    force: Vector3 = field(default_factory=Vector3)
    torque: Vector3 = field(default_factory=Vector3)


@dataclass
class WrenchStamped(IdlStruct, typename="geometry_msgs/msg/WrenchStamped"):
    header: Header = field(default_factory=Header)
    wrench: Wrench = field(default_factory=Wrench)


@dataclass
class Point32(IdlStruct, typename="geometry_msgs/msg/Point32"):
    x: float32 = 0.0
    y: float32 = 0.0
    z: float32 = 0.0


@dataclass
class Polygon(IdlStruct, typename="geometry_msgs/msg/Polygon"):
    points: sequence[Point32] = _list()


@dataclass
class PolygonStamped(IdlStruct, typename="geometry_msgs/msg/PolygonStamped"):
    header: Header = field(default_factory=Header)
    polygon: Polygon = field(default_factory=Polygon)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs/msg/Transform"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs/msg/TransformStamped"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs/msg/TFMessage"):
    transforms: sequence[TransformStamped] = _list()


# ---- sensor_msgs ----

@dataclass
class Imu(IdlStruct, typename="sensor_msgs/msg/Imu"):
    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: array[float64, 9] = _zeros(9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: array[float64, 9] = _zeros(9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: array[float64, 9] = _zeros(9)


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
class MagneticField(IdlStruct, typename="sensor_msgs/msg/MagneticField"):
    header: Header = field(default_factory=Header)
    magnetic_field: Vector3 = field(default_factory=Vector3)  # tesla
    magnetic_field_covariance: array[float64, 9] = _zeros(9)


@dataclass
class NavSatStatus(IdlStruct, typename="sensor_msgs/msg/NavSatStatus"):
    status: int8 = -2  # STATUS_UNKNOWN; NO_FIX -1, FIX 0, SBAS_FIX 1, GBAS_FIX 2
    service: uint16 = 0


@dataclass
class NavSatFix(IdlStruct, typename="sensor_msgs/msg/NavSatFix"):
    header: Header = field(default_factory=Header)
    status: NavSatStatus = field(default_factory=NavSatStatus)
    latitude: float64 = 0.0  # degrees, + north
    longitude: float64 = 0.0  # degrees, + east
    altitude: float64 = 0.0  # m above the WGS 84 ellipsoid (NaN: none)
    position_covariance: array[float64, 9] = _zeros(9)
    position_covariance_type: uint8 = 0


@dataclass
class Range(IdlStruct, typename="sensor_msgs/msg/Range"):
    header: Header = field(default_factory=Header)
    radiation_type: uint8 = 0  # ULTRASOUND 0, INFRARED 1
    field_of_view: float32 = 0.0
    min_range: float32 = 0.0
    max_range: float32 = 0.0
    range: float32 = 0.0  # +inf: nothing within max_range, -inf: closer than min_range (REP 117)
    variance: float32 = 0.0


@dataclass
class RangeHumble(IdlStruct, typename="sensor_msgs/msg/Range"):
    """Range as Humble (and every distribution before Iron) defines it: no variance."""
    header: Header = field(default_factory=Header)
    radiation_type: uint8 = 0
    field_of_view: float32 = 0.0
    min_range: float32 = 0.0
    max_range: float32 = 0.0
    range: float32 = 0.0


@dataclass
class JointState(IdlStruct, typename="sensor_msgs/msg/JointState"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = _list()
    position: sequence[float64] = _list()  # each empty, or one per name
    velocity: sequence[float64] = _list()
    effort: sequence[float64] = _list()


@dataclass
class BatteryState(IdlStruct, typename="sensor_msgs/msg/BatteryState"):
    header: Header = field(default_factory=Header)
    voltage: float32 = 0.0  # V; this and the next, NaN when not measured
    temperature: float32 = 0.0  # °C
    current: float32 = 0.0  # A, negative when discharging
    charge: float32 = 0.0  # Ah
    capacity: float32 = 0.0  # Ah
    design_capacity: float32 = 0.0  # Ah
    percentage: float32 = 0.0  # 0..1
    power_supply_status: uint8 = 0
    power_supply_health: uint8 = 0
    power_supply_technology: uint8 = 0
    present: bool = False
    cell_voltage: sequence[float32] = _list()
    cell_temperature: sequence[float32] = _list()
    location: str = ""
    serial_number: str = ""


@dataclass
class Image(IdlStruct, typename="sensor_msgs/msg/Image"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = _bytes()


@dataclass
class CompressedImage(IdlStruct, typename="sensor_msgs/msg/CompressedImage"):
    header: Header = field(default_factory=Header)
    format: str = ""
    data: sequence[uint8] = _bytes()


@dataclass
class PointField(IdlStruct, typename="sensor_msgs/msg/PointField"):
    name: str = ""
    offset: uint32 = 0
    datatype: uint8 = 0  # INT8=1 UINT8=2 INT16=3 UINT16=4 INT32=5 UINT32=6 FLOAT32=7 FLOAT64=8
    count: uint32 = 1


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs/msg/PointCloud2"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    fields: sequence[PointField] = _list()
    is_bigendian: bool = False
    point_step: uint32 = 0
    row_step: uint32 = 0
    data: sequence[uint8] = _bytes()
    is_dense: bool = False


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs/msg/LaserScan"):
    header: Header = field(default_factory=Header)
    angle_min: float32 = 0.0
    angle_max: float32 = 0.0
    angle_increment: float32 = 0.0
    time_increment: float32 = 0.0
    scan_time: float32 = 0.0
    range_min: float32 = 0.0
    range_max: float32 = 0.0
    ranges: sequence[float32] = _list()
    intensities: sequence[float32] = _list()


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs/msg/RegionOfInterest"):
    x_offset: uint32 = 0
    y_offset: uint32 = 0
    height: uint32 = 0
    width: uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs/msg/CameraInfo"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    distortion_model: str = ""
    d: sequence[float64] = _list()
    k: array[float64, 9] = _zeros(9)
    r: array[float64, 9] = _zeros(9)
    p: array[float64, 12] = _zeros(12)
    binning_x: uint32 = 0
    binning_y: uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


# ---- nav_msgs ----

@dataclass
class Odometry(IdlStruct, typename="nav_msgs/msg/Odometry"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class Path(IdlStruct, typename="nav_msgs/msg/Path"):
    header: Header = field(default_factory=Header)
    poses: sequence[PoseStamped] = _list()


@dataclass
class MapMetaData(IdlStruct, typename="nav_msgs/msg/MapMetaData"):
    map_load_time: Time = field(default_factory=Time)
    resolution: float32 = 0.0
    width: uint32 = 0
    height: uint32 = 0
    origin: Pose = field(default_factory=Pose)


@dataclass
class OccupancyGrid(IdlStruct, typename="nav_msgs/msg/OccupancyGrid"):
    header: Header = field(default_factory=Header)
    info: MapMetaData = field(default_factory=MapMetaData)
    data: sequence[int8] = _signed_bytes()  # row-major from (0, 0); -1 unknown, 0..100 occupancy


# ---- visualization_msgs ----

@dataclass
class UVCoordinate(IdlStruct, typename="visualization_msgs/msg/UVCoordinate"):
    u: float32 = 0.0
    v: float32 = 0.0


@dataclass
class MeshFile(IdlStruct, typename="visualization_msgs/msg/MeshFile"):
    filename: str = ""
    data: sequence[uint8] = _bytes()


@dataclass
class Marker(IdlStruct, typename="visualization_msgs/msg/Marker"):
    header: Header = field(default_factory=Header)
    ns: str = ""
    id: int32 = 0
    type: int32 = 0
    action: int32 = 0
    pose: Pose = field(default_factory=Pose)
    scale: Vector3 = field(default_factory=Vector3)
    color: ColorRGBA = field(default_factory=ColorRGBA)
    lifetime: Duration = field(default_factory=Duration)
    frame_locked: bool = False
    points: sequence[Point] = _list()
    colors: sequence[ColorRGBA] = _list()
    texture_resource: str = ""
    texture: CompressedImage = field(default_factory=CompressedImage)
    uv_coordinates: sequence[UVCoordinate] = _list()
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile = field(default_factory=MeshFile)
    mesh_use_embedded_materials: bool = False


@dataclass
class MarkerArray(IdlStruct, typename="visualization_msgs/msg/MarkerArray"):
    markers: sequence[Marker] = _list()


# ---- diagnostic_msgs ----

@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs/msg/KeyValue"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticStatus"):
    level: uint8 = 0  # the .msg's byte (ros2.BYTE_FIELDS): OK 0, WARN 1, ERROR 2, STALE 3
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = _list()


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs/msg/DiagnosticArray"):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = _list()


# ---- nav2_msgs (amcl's particles) ----

@dataclass
class Particle(IdlStruct, typename="nav2_msgs/msg/Particle"):
    pose: Pose = field(default_factory=Pose)
    weight: float64 = 0.0


@dataclass
class ParticleCloud(IdlStruct, typename="nav2_msgs/msg/ParticleCloud"):
    header: Header = field(default_factory=Header)
    particles: sequence[Particle] = _list()


# ---- can_msgs ----

@dataclass
class CanFrame(IdlStruct, typename="can_msgs/msg/Frame"):
    header: Header = field(default_factory=Header)
    id: uint32 = 0
    is_rtr: bool = False
    is_extended: bool = False
    is_error: bool = False
    dlc: uint8 = 0
    data: array[uint8, 8] = field(default_factory=lambda: bytes(8))  # CDR gives uint8 arrays back as bytes


ALL = (Time, Duration, Header, String, Float64, Bool, Int8, Int16, Int32, Int64, UInt8, UInt16, UInt32, UInt64,
       Float32, ColorRGBA, Vector3, Point, Quaternion, Pose, PoseStamped, PoseWithCovariance, Twist,
       TwistWithCovariance, TwistStamped, Accel, AccelStamped, Vector3Stamped, PointStamped,
       PoseWithCovarianceStamped, PoseArray, TwistWithCovarianceStamped, AccelWithCovariance,
       AccelWithCovarianceStamped, Wrench, WrenchStamped, Point32, Polygon, PolygonStamped, MagneticField, Transform,
       TransformStamped, TFMessage, Imu, Temperature, FluidPressure, RelativeHumidity, Illuminance, NavSatStatus,
       NavSatFix, Range, JointState, BatteryState, Image, CompressedImage, PointField, PointCloud2, LaserScan,
       RegionOfInterest, CameraInfo, Odometry, Path, MapMetaData, OccupancyGrid, UVCoordinate, MeshFile, Marker,
       MarkerArray, KeyValue, DiagnosticStatus, DiagnosticArray, Particle, ParticleCloud, CanFrame)
MESSAGE_TYPES: dict[str, type[IdlStruct]] = {cls.__idl_typename__: cls for cls in ALL}  # type: ignore[attr-defined]
# The types whose Humble definition is not Jazzy's (ros2_msgs' are Jazzy's): what a Humble node
# sends (its rmw_zenoh keys say TypeHashNotSupported) or a Humble bag records is read with these
HUMBLE_VARIANTS: dict[str, type[IdlStruct]] = {"sensor_msgs/msg/Range": RangeHumble}
HUMBLE_HASH = "TypeHashNotSupported"  # the type hash of Humble's rmw_zenoh keys and tokens

# encapsulation kinds ROS 2 sends (plain CDR, big/little endian); XCDR2 and PL_CDR are not ROS 2 messages
ENCAPSULATIONS = {b"\x00\x00", b"\x00\x01"}


def _byte_arrays(cls) -> list[tuple[str, int]]:
    hints = typing.get_type_hints(cls, include_extras=True)
    return [(name, meta.length) for name, hint in hints.items()
            if isinstance(meta := getattr(hint, "__metadata__", (None,))[0], array)
            and getattr(meta.subtype, "__metadata__", (None,))[0] == "uint8"]


# pycdr2 reads a fixed uint8 array as one slice and, at the end of a truncated buffer, returns it
# short instead of failing: those fields (top-level ones: can_msgs/Frame's data) are checked here
BYTE_ARRAYS = {name: fields for name, cls in MESSAGE_TYPES.items() if (fields := _byte_arrays(cls))}


def decode(type_name: str, payload: bytes, humble: bool = False):
    """The message a payload holds, or CdrError saying why not (never another exception).
    humble: sent or recorded by Humble (HUMBLE_VARIANTS' definition where it has one)."""
    if len(payload) < 4 or payload[:2] not in ENCAPSULATIONS:
        raise CdrError(f"{type_name}: not a CDR encapsulation header: {payload[:4].hex() or 'empty payload'}")
    cls = (HUMBLE_VARIANTS.get(type_name) if humble else None) or MESSAGE_TYPES[type_name]
    try:
        msg = cls.deserialize(payload)
    except Exception as e:  # noqa: BLE001 - pycdr2 raises struct.error, IndexError, UnicodeDecodeError...
        raise CdrError(f"{type_name}: malformed CDR ({len(payload)} bytes): {e}") from None
    for name, length in BYTE_ARRAYS.get(type_name, ()):
        if len(getattr(msg, name)) != length:
            raise CdrError(f"{type_name}: malformed CDR ({len(payload)} bytes): {name} ends past the payload")
    return msg
