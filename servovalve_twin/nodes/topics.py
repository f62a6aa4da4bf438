"""The twin's topics and their messages: names (relative, so ``--ros-args -r __ns:=/left`` or
a twin's namespace moves a whole graph), types, units and publishers -- derived from the one
signal table (:mod:`~..physics.signals`) -- the QoS, and the message builders."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..physics.signals import SIGNAL_TABLE

#: Reliable, keep-last 10: the lockstep sends one message per topic and tick, and depth 1 was
#: measured to drop bursts (doc/design/ROS-LOCKSTEP.md).
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

#: topic -> (message type, unit, publisher, meaning): the docs' topic table is built from it.

#: topic -> (message type, unit, publisher, meaning): the docs' topic table is built from it.
TOPICS: dict[str, tuple[type, str, str, str]] = {
    s.name: (Float64, s.unit, s.source, f'{s.symbol}, {s.meaning}'
             + (' (HD only)' if s.ports else '')) for s in SIGNAL_TABLE}
TOPICS['joint_states'] = (JointState, 'm, m/s, N', 'plant',
                          "joint 'jack': position XJ, velocity DXJ, effort AJ*P12")
JOINT_NAME = 'jack'


def f64(value: float) -> Float64:
    msg = Float64()
    msg.data = float(value)
    return msg


def joint_state(stamp_ns: int, xj: float, dxj: float, force: float,
                msg: JointState | None = None) -> JointState:
    """The jack's joint state; pass ``msg`` to refill a message instead of building one."""
    if msg is None:
        msg = JointState()
        msg.name = [JOINT_NAME]
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.position = [float(xj)]
    msg.velocity = [float(dxj)]
    msg.effort = [float(force)]
    return msg


def type_name(msg_type: type) -> str:
    module = msg_type.__module__.split('.')
    return f'{module[0]}/msg/{msg_type.__name__}'


__all__ = ['QOS', 'TOPICS', 'JOINT_NAME', 'f64', 'joint_state', 'type_name']
