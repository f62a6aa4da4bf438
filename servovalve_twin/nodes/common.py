"""What every node shares: topic names and types, QoS, message <-> physics conversions, the
declaration of physical parameters from the one parameter schema, and the standalone ``main``.

Topics are relative names, so ``--ros-args -r __ns:=/eha`` moves a whole graph.
"""

from __future__ import annotations

import math
import signal
import sys
from collections import deque
from typing import Any, Callable, Iterable, Sequence

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..errors import ParameterError, TwinError
from ..physics.params import DEFAULTS, PARAM_FIELDS, EhaParams, param_table

#: Reliable, keep-last 10: the lockstep sends one message per topic and tick, and depth 1 was
#: measured to drop bursts (ROS-LOCKSTEP.md).
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

#: topic -> (message type, unit, publisher, meaning). The README's topic table is this.
TOPICS: dict[str, tuple[type, str, str, str]] = {
    'com': (Float64, 'm', 'command_generator', 'position command Com'),
    'fr': (Float64, 'N', 'scheduler', 'external load FR (> 0 opposes +XJ)'),
    'psr': (Float64, 'Pa', 'scheduler', 'supply-return pressure PSR'),
    'cor': (Float64, 'A', 'ecu', 'servovalve current Cor'),
    'xs': (Float64, 'm', 'plant', 'spool displacement XS'),
    'xj': (Float64, 'm', 'plant', 'jack position XJ'),
    'dxj': (Float64, 'm/s', 'plant', 'jack velocity DXJ'),
    'p12': (Float64, 'Pa', 'plant', 'differential pressure P12 = P1 - P2'),
    'qj': (Float64, 'm^3/s', 'plant', 'working flow QJ = AJ*DXJ'),
    'p1': (Float64, 'Pa', 'plant', 'port-1 absolute pressure (HD only)'),
    'p2': (Float64, 'Pa', 'plant', 'port-2 absolute pressure (HD only)'),
    'joint_states': (JointState, 'm, m/s, N', 'plant',
                     "joint 'jack': position XJ, velocity DXJ, effort AJ*P12"),
}
JOINT_NAME = 'jack'


class TwinNode(Node):
    """A node whose publications go through :meth:`emit`, so that the twin's recorder can take
    every message at the moment it is published (``tap``), without a subscription per topic.
    Alone, ``tap`` is None and :meth:`emit` is a plain publish."""

    def __init__(self, name: str, **kwargs):
        super().__init__(name, **kwargs)
        self.pubs: dict[str, Any] = {}
        self._f64: dict[str, Float64] = {}
        self.tap: Callable[[str, Any], None] | None = None

    def add_publishers(self, topics: Iterable[str], table: dict | None = None) -> None:
        """Publishers for ``topics``, typed from ``table`` (default :data:`TOPICS`)."""
        table = TOPICS if table is None else table
        for t in topics:
            self.pubs[t] = self.create_publisher(table[t][0], t, QOS)

    def emit(self, topic: str, msg: Any) -> None:
        if self.tap is not None:
            self.tap(topic, msg)
        self.pubs[topic].publish(msg)

    def emit_value(self, topic: str, value: float) -> None:
        """Publish a Float64; one message object per topic is reused (publishing serializes it
        at once), which saves building a message per tick on the hot path."""
        msg = self._f64.get(topic)
        if msg is None:
            msg = self._f64[topic] = Float64()
        msg.data = float(value)
        self.emit(topic, msg)


class LockstepInputs:
    """A node's Float64 inputs: the latest value of each (alone, a timer reads those) and, in
    the lockstep, a queue per input from which each tick takes exactly one value, in arrival
    order -- so callback order cannot change a result. With ``ticked`` the node also waits
    for the orchestrator to open the tick (:meth:`begin`) with its time and sub-step count.
    A non-finite value is logged and dropped, never used."""

    def __init__(self, node: Node, defaults: dict[str, float], *, lockstep: bool,
                 ticked: bool = True):
        self.node = node
        self.latest = dict(defaults)
        self.lockstep = lockstep
        self.ticked = ticked
        self.queues: dict[str, deque] = {n: deque() for n in defaults}
        self.ticks: deque[tuple[int, int]] = deque()

    def push(self, name: str, msg: Float64) -> None:
        v = finite_or_none(msg.data, name, self.node)
        if v is None:
            return
        self.latest[name] = v
        if self.lockstep:
            self.queues[name].append(v)

    def begin(self, t_ns: int, n_sub: int) -> None:
        self.ticks.append((t_ns, n_sub))

    def pop(self) -> tuple[tuple[int, int] | None, dict[str, float]] | None:
        """The next complete tick, ``((t_ns, n_sub) or None, values)``, or None if incomplete."""
        if (self.ticks or not self.ticked) and all(self.queues.values()):
            tick = self.ticks.popleft() if self.ticked else None
            return tick, {n: q.popleft() for n, q in self.queues.items()}
        return None

    def pending(self) -> int:
        """Values queued beyond the tick: more than the lockstep sends means a foreign
        publisher on the same topics."""
        return max(len(q) for q in self.queues.values())


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


def finite_or_none(value: float, what: str, node: Node) -> float | None:
    """A received value if finite; a NaN/inf input is logged and dropped, never integrated."""
    if math.isfinite(value):
        return value
    node.get_logger().error(f'ignored non-finite {what} = {value!r}; keeping the last value',
                            throttle_duration_sec=1.0)
    return None


# -- parameters -----------------------------------------------------------------------------

_DERIVED_NOTE = '0.0 = derived'


def declare_physical(node: Node, names: Iterable[str] | None = None,
                     read_only: Sequence[str] = ('DT',)) -> None:
    """Declare parameters of :class:`EhaParams` with description, unit and range.

    Derived parameters (GM, V0, C4_alpha) are declared as 0.0 meaning "derived".
    """
    rows = {r['name']: r for r in param_table()}
    for name in names if names is not None else rows:
        r = rows[name]
        desc = ParameterDescriptor(
            name=name, description=f'{r["doc"]} [{r["unit"]}]'
            + (f'; {_DERIVED_NOTE}' if r['derived'] else ''),
            read_only=name in read_only)
        default: Any = r['default']
        if r['kind'] == 'bool':
            desc.type = ParameterType.PARAMETER_BOOL
        elif r['kind'] == 'int':
            desc.type = ParameterType.PARAMETER_INTEGER
            desc.integer_range = [IntegerRange(from_value=int(r['lo']), to_value=int(r['hi']),
                                               step=1)]
        else:
            desc.type = ParameterType.PARAMETER_DOUBLE
            lo = 0.0 if r['derived'] else float(r['lo'])
            desc.floating_point_range = [FloatingPointRange(from_value=lo,
                                                            to_value=float(r['hi']), step=0.0)]
            default = 0.0 if r['derived'] else float(default)
        node.declare_parameter(name, default, desc)


def physical_from_node(node: Node, names: Iterable[str] | None = None,
                       base: EhaParams = DEFAULTS) -> EhaParams:
    """The node's current physical parameters as :class:`EhaParams` (validated)."""
    changes = {}
    for name in names if names is not None else PARAM_FIELDS:
        changes[name] = node.get_parameter(name).value
    return with_ros_values(base, changes)


def with_ros_values(base: EhaParams, changes: dict[str, Any]) -> EhaParams:
    """``base`` with ROS parameter values applied (0.0 of a derived parameter = derived)."""
    fixed = {}
    for name, value in changes.items():
        if name not in PARAM_FIELDS:
            continue
        if PARAM_FIELDS[name].default is None and value == 0.0:
            value = None
        fixed[name] = value
    return base.replace(**fixed)


def validation_result(fn: Callable[[], Any]) -> SetParametersResult:
    """Run a validation; a :class:`TwinError` becomes a refusal with its message as reason."""
    try:
        fn()
    except TwinError as exc:
        return SetParametersResult(successful=False, reason=str(exc))
    return SetParametersResult(successful=True)


# -- standalone entry point -----------------------------------------------------------------

def spin_standalone(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Jazzy's idiom for a node run alone (``ros2 run`` / console script): SIGINT and SIGTERM
    end it cleanly; bad parameters at start-up are one line and exit code 2.

    rclpy's own signal handler shuts the context down under the executor, which then fails to
    build its wait set (a race seen with SIGTERM), and an exception raised by a Python handler
    inside a callback surfaces from pybind11 as a RuntimeError. So both signals only set a flag;
    the executor waits at most 0.1 s at a time (a sim-time timer whose ``/clock`` stopped never
    fires), sees it and leaves, and the ``finally`` below shuts down in order.
    """
    stop = []

    def request_stop(*_):
        stop.append(True)
    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    rclpy.init(args=list(args) if args is not None else sys.argv,
               signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    try:
        node = factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    except (TwinError, ParameterError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except rclpy.exceptions.ParameterException as exc:      # type/range at declare time
        print(f'error: {exc}', file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
