"""What every node shares: topic names and types, QoS, message <-> physics conversions, the
declaration of physical parameters from the one parameter schema, and the standalone ``main``.

Topics are relative names, so ``--ros-args -r __ns:=/eha`` moves a whole graph.
"""

from __future__ import annotations

import math
import signal
import sys
from pathlib import Path
from collections import deque
from typing import Any, Callable, Iterable, Sequence

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..errors import ParameterError, TwinError
from ..physics.params import DEFAULTS, PARAM_FIELDS, EhaParams, names_read_by, param_table

#: Reliable, keep-last 10: the lockstep sends one message per topic and tick, and depth 1 was
#: measured to drop bursts (doc/design/ROS-LOCKSTEP.md).
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

#: topic -> (message type, unit, publisher, meaning): the docs' topic table is built from it.
TOPICS: dict[str, tuple[type, str, str, str]] = {
    'com': (Float64, 'm', 'command_generator', 'position command Com'),
    'fr': (Float64, 'N', 'load_supply', 'external load FR (> 0 opposes +XJ)'),
    'psr': (Float64, 'Pa', 'load_supply', 'supply-return pressure PSR'),
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
    """The skeleton every twin node shares, written once.

    - **parameters**: ``control_period`` (s, read-only) and, when ``subsystem`` names one of
      :data:`~..physics.params.SUBSYSTEMS`, exactly the physical parameters it reads
      (:meth:`declared_physical`), declared from the one schema with unit and range; every set is
      validated as a whole (:meth:`check_parameters`, a refusal keeps the old values) and then
      applied (:meth:`apply_parameters`), so ``self.params`` always holds valid values;
    - **inputs**: Float64 subscriptions into a :class:`LockstepInputs` (:meth:`start_inputs`);
      each arrival calls :meth:`try_tick`, which runs :meth:`step` once a tick is complete. In
      the twin the inputs come from the other in-process nodes through a :class:`LocalBus`
      instead of a DDS round trip;
    - **drive**: in the lockstep the orchestrator opens the ticks; alone, a timer at
      ``control_period`` calls :meth:`on_timer` (:meth:`start`, called last by every node);
    - **outputs**: publications go through :meth:`emit`, so that the twin's recorder can take
      every message at the moment it is published (``tap``), without a subscription per topic;
      in the twin a topic goes out on DDS only while something subscribes to it
      (:meth:`refresh_subscribers`).
    """

    subsystem: str | None = None
    period_doc = 'control period [s]: inputs are held over it'

    @classmethod
    def declared_physical(cls) -> tuple[str, ...]:
        """The physical parameters this node declares: those its subsystem reads."""
        return names_read_by(cls.subsystem) if cls.subsystem else ()

    def __init__(self, name: str, *, lockstep: bool = False, params: EhaParams | None = None,
                 bus: 'LocalBus | None' = None, **kwargs):
        super().__init__(name, **kwargs)
        self.lockstep = lockstep
        self.bus = bus
        self.pubs: dict[str, Any] = {}
        #: topic -> something subscribes on DDS (refreshed by the twin; publish when unknown)
        self._wanted: dict[str, bool] = {}
        self._f64: dict[str, Float64] = {}
        self.tap: Callable[[str, Any], None] | None = None
        #: the recorder's faster taps (twin): a Float64 value, an encoded message
        self.tap_value: Callable[[str, float], None] | None = None
        self.tap_bytes: Callable[[str, bytes], None] | None = None
        self.io: LockstepInputs | None = None
        self.done = -1                     # ticks completed (lockstep)
        self.declare_parameter('control_period', 0.001, ParameterDescriptor(
            description=self.period_doc, read_only=True))
        self.period = float(self.get_parameter('control_period').value)
        self.physical = self.declared_physical()
        declare_physical(self, self.physical)
        # the twin hands over the run's parameters (its ROS parameters are set to the same
        # values, derived ones as 0.0 = derived); alone, they are the declared ones
        self.params = (params if params is not None
                       else physical_from_node(self, self.physical, DEFAULTS))
        # the parameter callbacks go live in start(): the subclass's own declarations are not
        # parameter *sets* and must not reach check/apply before the node is built
        self._started = False
        doubles = {n for n in self.physical if PARAM_FIELDS[n].metadata['kind'] == 'float'}
        self.add_pre_set_parameters_callback(lambda ps: integers_as_doubles(ps, doubles))
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)

    # -- parameters -----------------------------------------------------------------------
    def check_parameters(self, changes: dict[str, Any]) -> None:
        """Raise :class:`TwinError` to refuse a set; the default checks the physical values
        (range and cross-parameter rules) against the current ones."""
        with_ros_values(self.params, changes)

    def apply_parameters(self, changes: dict[str, Any]) -> None:
        """Apply a validated set; the default takes the physical values into ``params`` and
        hands them to :meth:`on_params` when there are any."""
        physical = {k: v for k, v in changes.items() if k in PARAM_FIELDS}
        if physical:
            self.params = with_ros_values(self.params, physical)
            self.on_params(self.params)

    def on_params(self, params: EhaParams) -> None:
        """New physical parameters are in force (a fault, a retune)."""

    def _validate(self, params: list[Parameter]) -> SetParametersResult:
        if not self._started:
            return SetParametersResult(successful=True)
        return validation_result(lambda: self.check_parameters(
            {p.name: p.value for p in params}))

    def _apply(self, params: list[Parameter]) -> None:
        if self._started:
            self.apply_parameters({p.name: p.value for p in params})

    # -- inputs and drive -------------------------------------------------------------------
    def start_inputs(self, defaults: dict[str, float], *, ticked: bool = True) -> None:
        """Subscribe to the Float64 inputs ``defaults`` names (their values until the first
        messages arrive, alone)."""
        self.io = LockstepInputs(self, defaults, lockstep=self.lockstep, ticked=ticked)
        for name in defaults:
            if self.bus is not None:
                self.bus.subscribe(name, lambda v, n=name: self._on_input(n, v))
            else:
                self.create_subscription(Float64, name,
                                         lambda m, n=name: self._on_input(n, m.data), QOS)

    def _on_input(self, name: str, value: float) -> None:
        self.io.push(name, value)
        self.try_tick()

    def begin_tick(self, t_ns: int, n_sub: int) -> None:
        """Lockstep: the orchestrator opens the tick at ``t_ns`` (``n_sub`` DT sub-steps to
        integrate; 0 at the run's end instant)."""
        self.io.begin(t_ns, n_sub)
        self.try_tick()

    def try_tick(self) -> None:
        ready = self.io.pop() if self.lockstep else None
        if ready is not None:
            tick, values = ready
            self.step(tick, values)
            self.done += 1

    def step(self, tick: tuple[int, int] | None, values: dict[str, float]) -> None:
        """One lockstep tick with exactly one value of each input."""
        raise NotImplementedError

    def start(self) -> None:
        """The node is built: parameter sets are checked and applied from now on, and alone a
        timer drives :meth:`on_timer` every ``control_period`` on the node's clock."""
        self._started = True
        if not self.lockstep:
            self.create_timer(self.period, self.on_timer)

    def on_timer(self) -> None:
        raise NotImplementedError

    # -- outputs ----------------------------------------------------------------------------
    def add_publishers(self, topics: Iterable[str], table: dict | None = None) -> None:
        """Publishers for ``topics``, typed from ``table`` (default :data:`TOPICS`)."""
        table = TOPICS if table is None else table
        for t in topics:
            self.pubs[t] = self.create_publisher(table[t][0], t, QOS)

    def emit(self, topic: str, msg: Any) -> None:
        if self.tap is not None:
            self.tap(topic, msg)
        if self.bus is not None:
            if topic in self.bus.routes:
                self.bus.post(topic, msg.data)
            if not self.wanted(topic):
                return          # nobody on DDS: serializing it would cost ~3 us for nothing
        self.pubs[topic].publish(msg)

    def wanted(self, topic: str) -> bool:
        """Whether ``topic`` goes out on DDS: always alone; in the twin while something on the
        graph subscribes (as of the last :meth:`refresh_subscribers`)."""
        return self.bus is None or self._wanted.get(topic, True)

    def refresh_subscribers(self) -> None:
        """Note which topics have DDS subscribers (the twin calls this every 100 ms): a
        viewer that subscribes mid-run receives the topic from the next refresh on."""
        for topic, pub in self.pubs.items():
            self._wanted[topic] = pub.get_subscription_count() > 0

    def emit_value(self, topic: str, value: float) -> None:
        """Publish a Float64; one message object per topic is reused (publishing serializes it
        at once), which saves building a message per tick on the hot path. In the twin the
        value goes to the recorder and the in-process subscribers as a float, and a message
        is filled only when something on DDS subscribes."""
        value = float(value)
        if self.bus is not None:
            if self.tap_value is not None:
                self.tap_value(topic, value)
            if topic in self.bus.routes:
                self.bus.post(topic, value)
            if not self._wanted.get(topic, True):
                return
            self._message(topic, value)
            self.pubs[topic].publish(self._f64[topic])
            return
        self.emit(topic, self._message(topic, value))

    def _message(self, topic: str, value: float) -> Float64:
        msg = self._f64.get(topic)
        if msg is None:
            msg = self._f64[topic] = Float64()
        msg.data = value
        return msg


#: physical bounds of an input topic: a value outside is dropped like a NaN (a 1e300 or negative
#: supply pressure would otherwise be integrated and published as P12 = +-1e300)
INPUT_LIMITS = {'psr': (0.0, 1.0e8)}


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
        self._limits = {n: INPUT_LIMITS.get(n, (-math.inf, math.inf)) for n in defaults}
        self._empty = len(self.queues)          # queues without a value (a tick needs none)

    def push(self, name: str, value: float) -> None:
        v = value if math.isfinite(value) else finite_or_none(value, name, self.node)
        if v is None:
            return
        lo, hi = self._limits[name]
        if not lo <= v <= hi:
            self.node.get_logger().error(f'ignored {name} = {v!r} outside [{lo:g}, {hi:g}]; '
                                         'keeping the last value', throttle_duration_sec=1.0)
            return
        self.latest[name] = v
        if self.lockstep:
            queue = self.queues[name]
            if not queue:
                self._empty -= 1
            queue.append(v)

    def begin(self, t_ns: int, n_sub: int) -> None:
        self.ticks.append((t_ns, n_sub))

    def pop(self) -> tuple[tuple[int, int] | None, dict[str, float]] | None:
        """The next complete tick, ``((t_ns, n_sub) or None, values)``, or None if incomplete."""
        if self._empty == 0 and (self.ticks or not self.ticked):
            tick = self.ticks.popleft() if self.ticked else None
            values = {n: q.popleft() for n, q in self.queues.items()}
            self._empty = sum(1 for q in self.queues.values() if not q)
            return tick, values
        return None


class LocalBus:
    """The twin's in-process delivery of Float64 values between its nodes.

    Every lockstep input would otherwise make a DDS round trip inside one process (publish,
    serialize, deliver, executor wake-up: ~12 us each, ~83 us per tick, bench/README.md). A
    value posted here is queued for each in-process subscriber and delivered by :meth:`drain`
    in posting order, one callback at a time -- the order the executor delivered in, so each
    node still consumes each input once and in order, and the run and its bag are unchanged.
    The topics are still published on DDS for the rest of the graph whenever something there
    subscribes (:meth:`TwinNode.emit`).
    """

    def __init__(self):
        self.routes: dict[str, list[Callable[[float], None]]] = {}
        self.queue: deque = deque()

    def subscribe(self, topic: str, callback: Callable[[float], None]) -> None:
        self.routes.setdefault(topic, []).append(callback)

    def post(self, topic: str, value: float) -> None:
        for callback in self.routes.get(topic, ()):
            self.queue.append((callback, value))

    def drain(self) -> None:
        """Deliver until nothing is queued (a delivery may post more: Cor, then P12...)."""
        queue = self.queue
        while queue:
            callback, value = queue.popleft()
            callback(value)


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


def declare_physical(node: Node, names: Iterable[str],
                     read_only: Sequence[str] = ('DT',)) -> None:
    """Declare parameters of :class:`EhaParams` with description, unit and range.

    Derived parameters (GM, V0, C4_alpha) are declared as 0.0 meaning "derived".
    """
    rows = {r['name']: r for r in param_table()}
    for name in names:
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
            # `-p M:=400` (an integer for a double) is a value, not a type error: the set is
            # checked and coerced by the node's own validation
            desc.dynamic_typing = True
            lo = 0.0 if r['derived'] else float(r['lo'])
            desc.floating_point_range = [FloatingPointRange(from_value=lo,
                                                            to_value=float(r['hi']), step=0.0)]
            default = 0.0 if r['derived'] else float(default)
        node.declare_parameter(name, default, desc)
        value = node.get_parameter(name).value
        if r['kind'] == 'float' and isinstance(value, int) and not isinstance(value, bool):
            # `-p M:=400` given at start-up: stored as the double it means (before any
            # parameter callback exists, so this is not a parameter *set*)
            node.set_parameters([Parameter(name, Parameter.Type.DOUBLE, float(value))])


def integers_as_doubles(params: list[Parameter], doubles) -> list[Parameter]:
    """A pre-set callback's work: an integer given for a double parameter (``ros2 param set
    /plant M 450``) becomes that double, so that it reads back as one."""
    return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in doubles and p.type_ == Parameter.Type.INTEGER else p for p in params]


def physical_from_node(node: Node, names: Iterable[str],
                       base: EhaParams = DEFAULTS) -> EhaParams:
    """``base`` with the node's current values of the parameters ``names`` (validated)."""
    return with_ros_values(base, {name: node.get_parameter(name).value for name in names})


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

def _refuse_unknown_parameters(node: Node) -> None:
    """A ``-p NAME:=VALUE`` the node does not declare is a misspelling, unless it is a physical
    parameter another node reads (one ``--params-file config/eha.yaml`` serves every node)."""
    from ..physics.params import PARAM_NAMES
    given = getattr(node, '_parameter_overrides', {}) or {}
    unknown = sorted(n for n in given if not node.has_parameter(n) and n not in PARAM_NAMES
                     and not n.startswith('qos_overrides.'))
    if unknown:
        declared = sorted(n for n in node._parameters if n not in PARAM_NAMES)
        raise TwinError(f'node {node.get_name()} has no parameter {unknown[0]!r}; it declares '
                        f'{declared} and the physical parameters it reads')


def describe(node: Node) -> str:
    """What a node runs with, in one line: its models, control period and time source."""
    parts = []
    for name in ('valve_model', 'monitor_model', 'scenario'):
        if node.has_parameter(name):
            parts.append(f'{name} {node.get_parameter(name).value}')
    if node.has_parameter('control_period'):
        parts.append(f'control period {node.get_parameter("control_period").value:g} s')
    sim = node.get_parameter('use_sim_time').value
    parts.append('simulated time (/clock)' if sim else 'wall time')
    return ', '.join(parts)


def spin_standalone(factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Jazzy's idiom for a node run alone (``ros2 run`` / console script): SIGINT and SIGTERM
    end it cleanly; bad parameters at start-up are one line and exit code 2.

    rclpy's own signal handler shuts the context down under the executor, which then fails to
    build its wait set (a race seen with SIGTERM), and an exception raised by a Python handler
    inside a callback surfaces from pybind11 as a RuntimeError. So both signals only set a flag;
    the executor waits at most 0.1 s at a time (a sim-time timer whose ``/clock`` stopped never
    fires), sees it and leaves, and the ``finally`` below shuts down in order.
    """
    argv = list(args) if args is not None else list(sys.argv)
    plain = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if plain:
        doc = (getattr(factory, '__doc__', None) or '').strip()
        print(f'usage: {Path(argv[0]).name} [--ros-args -p NAME:=VALUE ... '
              f'[--params-file FILE]]\n\n{doc}')
        return 0 if plain[0] in ('-h', '--help') else 2
    stop = []

    def request_stop(*_):
        stop.append(True)
    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy._rclpy_pybind11.RCLError as exc:       # e.g. a params file that is missing
        print(f'error: {" ".join(str(exc).split(", at ")[0].split())}', file=sys.stderr)
        return 2
    node = executor = None
    if stop:            # asked to stop while rclpy started: do not build (and compile) a node
        rclpy.try_shutdown()
        return 0
    try:
        node = factory()
        _refuse_unknown_parameters(node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # one start-up line; it also tells a supervisor (and the tests) that the signal
        # handlers are in place and the node is up
        node.get_logger().info('started: ' + describe(node))
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    except (TwinError, ParameterError, rclpy.exceptions.ParameterException) as exc:
        # (the last: type or range refused at declare time) -- one line, of bounded length
        text = ' '.join(str(exc).split())
        print(f'error: {text[:600]}' + (' ...' if len(text) > 600 else ''), file=sys.stderr)
        return 2
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
