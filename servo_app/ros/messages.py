"""ROS 2 message types (ROS 2 Jazzy definitions, CDR little-endian) and builders from servo_app data.

One typestore serves every consumer that leaves the machine, so an MCAP log and a live topic carry
the same bytes. The standard types come from ``rosbags`` (a pure-Python library with the ROS 2
message definitions); two types of our own, in ``servo_app_msgs``, carry what has no standard type.

Joint states follow ROS-Industrial's FANUC description: ``joint_1``..``joint_6`` in radians, in the
model convention (J3 measured from J2, as the URDF's kinematic chain does), not FANUC's J2/J3
coupled degrees. Poses are in metres in the robot's world frame ``base``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

DISTRIBUTION = "jazzy"
FRAME_BASE = "base"

LIMIT_USAGE = "servo_app_msgs/msg/LimitUsage"
STATUS_BITS = "servo_app_msgs/msg/StatusBits"
JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
JOINT_JOG = "control_msgs/msg/JointJog"
STRING = "std_msgs/msg/String"
EMPTY = "std_msgs/msg/Empty"

_OWN_TYPES = {
    LIMIT_USAGE: """\
# Share of the controller's limits each axis uses, in %: finite differences at the fixed interval,
# against the limits at the current flange speed (FANUC J519 Appendix B).
std_msgs/Header header
string[] name
float64[] velocity_pct
float64[] acceleration_pct
float64[] jerk_pct
float64 flange_speed_mm_s
""",
    STATUS_BITS: """\
# One status datagram's flags as received: FANUC J519 status bits / Janome robot state.
std_msgs/Header header
uint32 seq
uint8 bits
uint16 io
string[] set
""",
}

# control_msgs is not in rosbags' Jazzy store: its standard definition (control_msgs 4.x, as MoveIt
# Servo's delta_joint_cmds uses it), registered under its real name so its RIHS01 hash is the ROS one.
_STANDARD_MISSING = {
    JOINT_JOG: """\
std_msgs/Header header
string[] joint_names
float64[] displacements
float64[] velocities
float64 duration
""",
}

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
for _name, _text in {**_STANDARD_MISSING, **_OWN_TYPES}.items():
    TYPESTORE.register(get_types_from_msg(_text, _name))

_T = TYPESTORE.types
Time = _T["builtin_interfaces/msg/Time"]
Header = _T["std_msgs/msg/Header"]
JointState = _T[JOINT_STATE]
PoseStamped = _T[POSE_STAMPED]
Pose = _T["geometry_msgs/msg/Pose"]
Point = _T["geometry_msgs/msg/Point"]
Quaternion = _T["geometry_msgs/msg/Quaternion"]
DiagnosticArray = _T[DIAGNOSTIC_ARRAY]
DiagnosticStatus = _T["diagnostic_msgs/msg/DiagnosticStatus"]
KeyValue = _T["diagnostic_msgs/msg/KeyValue"]
LimitUsage = _T[LIMIT_USAGE]
TwistStamped = _T[TWIST_STAMPED]
Twist = _T["geometry_msgs/msg/Twist"]
Vector3 = _T["geometry_msgs/msg/Vector3"]
JointJog = _T[JOINT_JOG]
String = _T[STRING]
Empty = _T[EMPTY]
StatusBits = _T[STATUS_BITS]


def msgdef(typename: str) -> str:
    """The ROS 2 ``.msg`` text of a type with its dependencies (the ``ros2msg`` schema encoding)."""
    return TYPESTORE.generate_msgdef(typename, ros_version=2)[0]


def serialize(message: Any, typename: str) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(message, typename))


def deserialize(data: bytes, typename: str) -> Any:
    return TYPESTORE.deserialize_cdr(data, typename)


def type_hash(typename: str) -> str:
    """The type's RIHS01 hash (``RIHS01_<64 hex>``), as ROS 2 Iron and later name types on the wire."""
    return str(TYPESTORE.hash_rihs01(typename))


def stamp_ns(msg_header: Any) -> int:
    return int(msg_header.stamp.sec) * 1_000_000_000 + int(msg_header.stamp.nanosec)


def header(t_ns: int, frame_id: str = FRAME_BASE) -> Any:
    """A header stamped ``t_ns`` (nanoseconds since the Unix epoch)."""
    ns = int(t_ns)
    return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame_id)


def joint_names(n: int) -> list[str]:
    return [f"joint_{i + 1}" for i in range(n)]


def joint_state(t_ns: int, position_rad: Sequence[float] | np.ndarray,
                velocity_rad_s: Sequence[float] | np.ndarray | None = None) -> Any:
    pos = np.asarray(position_rad, dtype=np.float64)
    vel = np.asarray([] if velocity_rad_s is None else velocity_rad_s, dtype=np.float64)
    return JointState(header=header(t_ns, ""), name=joint_names(len(pos)), position=pos, velocity=vel,
                      effort=np.zeros(0, dtype=np.float64))


def rotation_to_quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (Shepperd's method: stable for every rotation)."""
    m = np.asarray(r, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * np.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    return float(x), float(y), float(z), float(w)


def pose_stamped(t_ns: int, pose: np.ndarray, frame_id: str = FRAME_BASE) -> Any:
    """From a 4x4 homogeneous transform in metres."""
    x, y, z, w = rotation_to_quaternion(pose[:3, :3])
    return PoseStamped(header=header(t_ns, frame_id),
                       pose=Pose(position=Point(x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3])),
                                 orientation=Quaternion(x=x, y=y, z=z, w=w)))


def limit_usage(t_ns: int, names: list[str], velocity_pct: np.ndarray, acceleration_pct: np.ndarray,
                jerk_pct: np.ndarray, flange_speed_mm_s: float) -> Any:
    f = np.float64
    return LimitUsage(header=header(t_ns, ""), name=names, velocity_pct=np.asarray(velocity_pct, f),
                      acceleration_pct=np.asarray(acceleration_pct, f), jerk_pct=np.asarray(jerk_pct, f),
                      flange_speed_mm_s=float(flange_speed_mm_s))


def status_bits(t_ns: int, seq: int, bits: int, io: int, set_names: list[str]) -> Any:
    return StatusBits(header=header(t_ns, ""), seq=int(seq), bits=int(bits), io=int(io), set=set_names)


# DiagnosticStatus levels (bytes in the message definition).
OK, WARN, ERROR = 0, 1, 2


def diagnostics(t_ns: int, name: str, hardware_id: str,
                entries: list[tuple[int, str, dict[str, str]]]) -> Any:
    """One DiagnosticArray: each entry is (level, message, key/values)."""
    status = [DiagnosticStatus(level=int(level), name=name, message=message,
                               hardware_id=hardware_id,
                               values=[KeyValue(key=k, value=v) for k, v in values.items()])
              for level, message, values in entries]
    return DiagnosticArray(header=header(t_ns, ""), status=status)


def twist_stamped(t_ns: int, linear: Sequence[float], angular: Sequence[float], frame_id: str = FRAME_BASE) -> Any:
    """m/s and rad/s, as MoveIt Servo's ``delta_twist_cmds``."""
    return TwistStamped(header=header(t_ns, frame_id), twist=Twist(
        linear=Vector3(x=float(linear[0]), y=float(linear[1]), z=float(linear[2])),
        angular=Vector3(x=float(angular[0]), y=float(angular[1]), z=float(angular[2]))))


def joint_jog(t_ns: int, names: list[str], velocities: Sequence[float], duration_s: float = 0.0) -> Any:
    """Joint velocities (rad/s or m/s), as MoveIt Servo's ``delta_joint_cmds``."""
    return JointJog(header=header(t_ns, ""), joint_names=list(names),
                    displacements=np.zeros(0, dtype=np.float64),
                    velocities=np.asarray(velocities, dtype=np.float64), duration=float(duration_s))


def pose_matrix(msg_pose: Any) -> np.ndarray:
    """A ``geometry_msgs/Pose`` as a 4x4 homogeneous transform (metres); the quaternion normalised."""
    o, p = msg_pose.orientation, msg_pose.position
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError(f"the orientation quaternion {q.tolist()} has no rotation (zero or not finite)")
    x, y, z, w = q / n
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [p.x, p.y, p.z]
    return m


def string(text: str) -> Any:
    return String(data=text)
