"""The skeleton every twin node shares (:class:`TwinNode`): parameters, lockstep inputs,
drive, outputs."""

from __future__ import annotations

from typing import Any, Callable, Iterable

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from ..physics.params import DEFAULTS, PARAM_FIELDS, EhaParams, names_read_by
from .inputs import LockstepInputs, LocalBus
from .parameters import (declare_physical, integers_as_doubles, physical_from_node,
                         validation_result, with_ros_values)
from .topics import QOS, TOPICS

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


__all__ = ['TwinNode']
