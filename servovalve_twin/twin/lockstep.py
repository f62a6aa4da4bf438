"""``twin``: the four nodes of the actuator (and the monitor and users' algorithm nodes when
asked), a clock driver and a bag recorder in one ``EventsExecutor`` on simulated time, in
deterministic lockstep.

Per control period k (t = k*Tc, an integer count of nanoseconds; doc/design/ROS-LOCKSTEP.md):

1. ``/clock`` is published with t (every node has ``use_sim_time`` true);
2. the plant publishes its state at t (XS, XJ, DXJ);
3. the command generator and the load and supply node publish Com, FR, PSR at t;
4. the values are delivered until the tick is complete: the ECU computes Cor once it holds
   that tick's Com and XJ; the plant, once it holds Cor, FR and PSR, publishes P12, QJ (P1, P2)
   and the joint state at t and integrates [t, t + Tc) in DT sub-steps; the monitor and the
   algorithm nodes step once they hold that tick's value of each of their inputs;
5. only then does the clock advance. The last tick (t = duration) evaluates without
   integrating, so the run's last 1 ms row is complete.

The nodes of one twin hand their Float64 values to each other in process
(:class:`~..nodes.inputs.LocalBus`, in publishing order, each consumed once): a DDS round trip
per input cost more than everything else in a tick. Every topic is still published on DDS while
something on the graph subscribes to it, and recorded whatever subscribes. Every 100 ms of
simulated time (:data:`GRAPH_PERIOD_NS`) the twin looks for new subscribers and lets the
executor handle what has arrived (the nodes' ``/clock``, so their clocks follow simulated time;
parameter requests from outside). ``/clock`` is recorded every ``clock_period``, and
published on DDS at each turn and, while a node outside the twin subscribes to it, every
``clock_period`` too.

Each input is consumed in order of arrival and exactly once, so the result does not depend on
callback order; the physics is the one :func:`~servovalve_twin.physics.simulate.simulate` runs,
so ``twin`` equals ``simulate`` with the same sampled ECU period. SIGINT and SIGTERM stop the
loop at a tick boundary (``EventsExecutor`` ignores both) and the bag is finalized.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.validate_namespace import validate_namespace
from rclpy.exceptions import InvalidNamespaceException
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Empty

from ..bag.provenance import PROVENANCE, Provenance
from ..bag.recorder import Recorder
from ..bag.table import signal_table
from ..bag.writer import BagWriter
from ..config import load_scenario
from ..errors import TwinError
from ..nodes.algorithm import AlgorithmNode, algorithm_topics, verdict
from ..nodes.clock import clock_msg
from ..nodes.base import TwinNode
from ..nodes.inputs import LocalBus
from ..nodes.topics import QOS, TOPICS
from ..nodes.ecu import Ecu
from ..nodes.monitor import MONITOR_TOPICS, Monitor
from ..nodes.plant import Plant
from ..nodes.sources import CommandGenerator, LoadSupply
from ..physics.params import EhaParams
from ..physics.scenario import Scenario
from ..physics.simulate import OUTPUT_PERIOD_NS, effective_params, steps_per
from ..physics.valves import get_monitor_model, get_valve_model
from ..prognostics.algorithm import load_algorithm
from .config import CLOCK_MODES

TICK_DEADLINE_S = 5.0
#: the longest sleep between two looks at a stop request (pacing, following)
PACE_SLICE_S = 0.05
#: following: how often (wall) a twin waiting for /clock checks that the owner is still there
OWNER_CHECK_S = 2.0
#: how long the clock owner waits at the end for its last /clock to reach the followers
CLOCK_ACK_S = 2.0
#: /clock from its owner: the latest time is all that counts, and a follower that joins late
#: (discovery) is handed it at once (transient local); rclpy's time sources (best effort,
#: volatile) match it
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: how often (simulated time) the executor gets a turn: node clocks and parameter requests
#: follow at this pace, external subscribers are noticed at it
GRAPH_PERIOD_NS = 100_000_000


def _events_executor(*, context: Context):
    """rclpy's EventsExecutor calls ``faulthandler.enable()`` on ``sys.stderr``, which fails
    where stderr is not a real file (Jupyter, pytest's capture): hand it the process's own."""
    try:
        sys.stderr.fileno()
        return EventsExecutor(context=context)
    except (AttributeError, OSError, ValueError):
        saved, sys.stderr = sys.stderr, sys.__stderr__
        try:
            return EventsExecutor(context=context)
        finally:
            sys.stderr = saved


#: rclpy's EventsExecutor was measured 8x cheaper per tick than the SingleThreadedExecutor
#: here (bench/bench_twin.py); the latter is kept for comparison.
EXECUTORS = {'events': _events_executor, 'single': SingleThreadedExecutor}


def _type_name(msg_type: type) -> str:
    module = msg_type.__module__.split('.')
    return f'{module[0]}/msg/{msg_type.__name__}'


@dataclasses.dataclass
class TwinResult:
    valve_model: str
    scenario: Scenario
    params: EhaParams
    control_period: float
    ticks: int
    wall_s: float
    simulated_s: float
    interrupted: bool = False
    bag: Path | None = None
    signals: dict[str, np.ndarray] | None = None
    messages: int = 0
    verdicts: list[str] = dataclasses.field(default_factory=list)   # monitor and algorithms


class Twin:
    """The in-process graph. Create, :meth:`run`, :meth:`close` (or use as a context manager).

    :param context: a private rclpy context (tests) or None for a new one
    :param bag: bag directory to record into, or None
    :param keep_values: keep the Float64 values to build the 1 ms signal table (``signals``)
    :param clock_period: ``/clock`` is published every this much simulated time (a multiple of
        the control period; default 10 ms). The lockstep does not need ``/clock`` -- every
        message is tied to its tick -- so it is decimated: at 1 ms each ``/clock`` message
        costs a delivery to every node's time source (bench/README.md)
    :param executor: 'events' (rclpy's EventsExecutor) or 'single' (SingleThreadedExecutor)
    :param foxglove: serve every message live to the Foxglove app on this localhost port (0:
        any free one; :mod:`..nodes.live`)
    :param namespace: the actuator's namespace ('left' or '/left'): its nodes, topics and the
        bag's topic names move under it (``/left/xj``); ``/clock`` stays global. A
        ``--ros-args -r __ns:=/left`` in ``args`` does the same
    :param clock: 'own' -- the twin publishes ``/clock``, the graph's one clock owner; or
        'follow' -- another owner (a twin, the ``clock`` executable) publishes it and this twin
        runs each tick only once ``/clock`` has reached it, so several actuators share one
        simulated time. A follower's results do not depend on the owner's pace (lockstep)
    :param real_time_factor: pace simulated time to this many simulated seconds per wall
        second (1.0: real time), checked at every ``clock_period``; None (default): as fast as
        possible. A paced twin publishes every ``/clock`` on DDS, so that a ``use_sim_time``
        node beside it sees each of its timer periods
    :param followers: the clock owner starts its run once this many twins that follow its
        ``/clock`` (other namespaces) are on the graph -- discovery takes 0.4-1.2 s here, and
        a follower that joins late misses no tick but the simulated time it waited for
    """

    def __init__(self, valve_model: str, scenario: str | Path | Scenario | Mapping = 'paper',
                 overrides: Mapping[str, Any] | None = None, *, control_period: float = 1e-3,
                 bag: str | Path | None = None, keep_values: bool = True,
                 context: Context | None = None, args: Sequence[str] | None = None,
                 domain_id: int | None = None, overwrite: bool = False,
                 clock_period: float = 1e-2, executor: str = 'events',
                 base_params: EhaParams | None = None,
                 on_flush: Callable[[float], None] | None = None,
                 monitor: str | None = None, algorithms: Sequence[Any] = (),
                 foxglove: int | None = None, namespace: str | None = None,
                 clock: str = 'own', real_time_factor: float | None = None,
                 followers: int = 0):
        get_valve_model(valve_model)
        if clock not in CLOCK_MODES:
            raise TwinError(f'clock {clock!r}: expected one of {", ".join(CLOCK_MODES)}')
        if real_time_factor is not None and not (
                math.isfinite(real_time_factor) and real_time_factor > 0):
            raise TwinError(f'real-time factor {real_time_factor}: expected a positive number '
                            '(1.0 is real time)')
        if real_time_factor is not None and clock == 'follow':
            raise TwinError('a twin that follows /clock is paced by the clock owner: give the '
                            'real-time factor to the owner')
        if followers and clock == 'follow':
            raise TwinError('followers: only the clock owner waits for its followers')
        if followers < 0:
            raise TwinError(f'followers {followers}: expected a count >= 0')
        self.follow = clock == 'follow'
        self.followers = int(followers)
        self.real_time_factor = real_time_factor
        self.scenario = load_scenario(scenario)
        self.params = effective_params(self.scenario, overrides, base_params)
        self.valve_model = valve_model
        self.control_period = control_period
        self.n_sub = steps_per(control_period, self.params, 'the control period')
        self.period_ns = self.n_sub * self.params.dt_ns
        if OUTPUT_PERIOD_NS % self.period_ns:
            raise TwinError(f'the control period {control_period} s must divide the 1 ms output '
                            'period')
        if self.scenario.duration_ns % self.period_ns:
            raise TwinError(f'the duration {self.scenario.duration} s is not a whole number of '
                            f'control periods of {control_period} s')
        self.clock_period_ns = int(round(clock_period * 1e9))
        if self.clock_period_ns <= 0 or self.clock_period_ns % self.period_ns:
            raise TwinError(f'the /clock period {clock_period} s must be a whole number of '
                            f'control periods of {control_period} s')
        #: the executor's turns (see _sync_graph): every /clock that falls on a 100 ms boundary
        self.graph_period_ns = self.clock_period_ns * max(
            1, GRAPH_PERIOD_NS // self.clock_period_ns)
        self._own_context = context is None
        self.context = context or Context()
        if not self.context.ok():
            rclpy.init(args=list(args) if args is not None else None, context=self.context,
                       domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.writer = None
        sim = Parameter('use_sim_time', Parameter.Type.BOOL, True)
        period = Parameter('control_period', Parameter.Type.DOUBLE, float(control_period))
        # the schedule nodes own the scenario loaded here, once; their parameter names it
        scn = Parameter('scenario', Parameter.Type.STRING, _scenario_label(scenario,
                                                                           self.scenario))
        self.bus = LocalBus()
        kw = dict(context=self.context, lockstep=True, bus=self.bus)
        if namespace:
            kw['namespace'] = _absolute_namespace(namespace)
        self.nodes: list[Node] = []
        if monitor is not None:
            get_monitor_model(monitor)
        try:
            self.command_generator = CommandGenerator(
                scenario=self.scenario, **kw, parameter_overrides=[sim, period, scn])
            self.load_supply = LoadSupply(scenario=self.scenario, **kw,
                                          parameter_overrides=[sim, period, scn])
            self.ecu = Ecu(params=self.params, **kw, parameter_overrides=[sim, period] + [
                _ros_param(n, self.params) for n in Ecu.declared_physical()])
            self.plant = Plant(params=self.params, **kw, parameter_overrides=[
                sim, period, Parameter('valve_model', Parameter.Type.STRING, valve_model)] + [
                _ros_param(n, self.params) for n in Plant.declared_physical()])
            self.clock = Node('twin_clock', context=self.context, parameter_overrides=[sim],
                              **({'namespace': kw['namespace']} if namespace else {}))
            #: where the actuator's topics live: '' or '/left' (an explicit namespace or a
            #: __ns remap among the context's arguments)
            self.namespace = self.plant.get_namespace().rstrip('/')
            self.clock_pub = None if self.follow else self.clock.create_publisher(
                Clock, '/clock', CLOCK_QOS)
            self._turn: Future | None = None
            self._owner_ns = -1         # the latest /clock seen (from the owner, following)
            self.clock.create_subscription(Clock, '/clock', self._on_clock,
                                           CLOCK_QOS if self.follow else QOS)
            if self.follow:
                # a follower's executor turns end at a message to itself on a hidden topic
                # (no /clock of its own to wait on; EventsExecutor takes no guard condition)
                self._turn_pub = self.clock.create_publisher(Empty, '~/_turn', QOS)
                self.clock.create_subscription(Empty, '~/_turn', self._on_turn, QOS)
            self.monitor = None
            topics = dict(TOPICS)
            if monitor is not None:
                # the monitor models the whole actuator with the nominal (pre-fault) values
                self.monitor = Monitor(params=self.params, **kw, parameter_overrides=[
                    sim, period, Parameter('monitor_model', Parameter.Type.STRING, monitor)]
                    + [_ros_param(n, self.params) for n in Monitor.declared_physical()])
                topics.update(MONITOR_TOPICS)
            # the user's algorithms: (class path or class, parameters) or instances
            self.algorithms = []
            for i, spec in enumerate(algorithms):
                cls, aparams = spec if isinstance(spec, tuple) else (spec, None)
                alg = load_algorithm(cls, aparams)
                name = getattr(alg, 'node_name', None) or (
                    'algorithm' if i == 0 else f'algorithm_{i + 1}')
                node = AlgorithmNode(alg, name=name,
                                     params=self.params, **kw,
                                     parameter_overrides=[sim, period])
                self.algorithms.append(node)
                topics.update(algorithm_topics(alg))
            types = {f'{self.namespace}/{t}': _type_name(spec[0])
                     for t, spec in topics.items()}
            types['/clock'] = 'rosgraph_msgs/msg/Clock'
            # the bag is opened once everything else has been accepted: a refused start-up
            # leaves no bag behind
            if bag is not None:
                self.writer = BagWriter(bag, overwrite=overwrite, flush_every_ns=None)
            self.recorder = Recorder(self.writer, types, keep_values=keep_values,
                                     namespace=self.namespace)
            self.recorder.on_flush = on_flush
            self.live = None
            if foxglove is not None:        # serve every recorded message to the Foxglove app
                from ..nodes.live import FoxgloveLive
                self.live = FoxgloveLive(types, port=foxglove)
                self.recorder.sinks.append(self.live.log)
            #: the actuator's nodes: a scheduled fault goes to every one that reads its parameter
            self.actuator = [self.ecu, self.plant]
            self.nodes = [self.command_generator, self.load_supply, self.ecu, self.plant,
                          self.clock] + ([self.monitor] if self.monitor else []) \
                + self.algorithms
            #: the nodes that complete a tick after the plant (they read its outputs)
            self.observers = ([self.monitor] if self.monitor else []) + self.algorithms
            for n in self.nodes:
                if n is not self.clock:
                    n.tap = self.recorder.record
                    n.tap_value = self.recorder.record_value
                    n.tap_bytes = self.recorder.record_bytes
            if executor not in EXECUTORS:
                raise TwinError(f'unknown executor {executor!r}; expected one of '
                                f'{sorted(EXECUTORS)}')
            self.executor = EXECUTORS[executor](context=self.context)
            for n in self.nodes:
                self.executor.add_node(n)
            self.plant.plant.compile()
            if self.monitor is not None:
                self.monitor.model.compile()
            if self.writer is not None:
                record = Provenance.build(valve_model, self.scenario, self.params,
                                          control_period, namespace=self.namespace)
                self.writer.add_metadata(PROVENANCE, record.to_record())
        except BaseException:          # a refusal, a failure or Ctrl-C during start-up
            if self.writer is not None:
                self.writer.abort()
                self.writer = None
            self.close()
            raise
        self.stop_requested = False
        self._warned_foreign = False
        self._clock_ns = -1             # the last /clock published
        self._turned_ns = -1            # ... and taken by the executor
        self._clock_wanted = True       # a node outside the twin subscribes to /clock

    def request_stop(self, *_: Any) -> None:
        """Stop at the next tick boundary (signal handlers call this)."""
        self.stop_requested = True

    def run(self, on_tick: Callable[[int, 'Twin'], None] | None = None) -> TwinResult:
        """Run the scenario; ``on_tick(k, twin)`` is called after each tick (faults, tests)."""
        n_ticks = self.scenario.duration_ns // self.period_ns
        # the whole schedule, evaluated once: the same values simulate() samples
        com, fr, psr = (a.tolist() for a in self.scenario.inputs(
            np.arange(n_ticks + 1, dtype=np.int64) * self.period_ns))
        faults = self._fault_ticks()
        if self.followers:
            self._wait_for_followers()
        wall = time.perf_counter()
        k = -1
        for k in range(n_ticks + 1):
            t_ns = k * self.period_ns
            if self.follow and t_ns > self._owner_ns:
                self._wait_for_clock(t_ns)
            elif self.real_time_factor is not None and t_ns % self.clock_period_ns == 0:
                self._pace(wall + t_ns * 1e-9 / self.real_time_factor)
            if self.stop_requested:
                k -= 1
                break
            self.recorder.now_ns = t_ns
            if t_ns % self.clock_period_ns == 0:
                msg = clock_msg(t_ns)
                self.recorder.record('/clock', msg)
                # on DDS: at every turn, and every period while a node outside the twin listens
                # or the run is paced for one
                if self.clock_pub is not None and (
                        self._clock_wanted or self.real_time_factor is not None
                        or t_ns % self.graph_period_ns == 0):
                    self._clock_ns = t_ns
                    self.clock_pub.publish(msg)
            if k in faults:
                self._inject(faults[k], t_ns)
            n_sub = self.n_sub if k < n_ticks else 0      # the end instant: evaluate only
            for node in self.observers:
                node.begin_tick(t_ns, n_sub)
            self.plant.begin_tick(t_ns, n_sub)
            self.command_generator.publish_values({'com': com[k]})
            self.load_supply.publish_values({'fr': fr[k], 'psr': psr[k]})
            self.bus.drain()
            late = [n.get_name() for n in [self.plant] + self.observers if n.done < k]
            if late:
                raise TwinError(f'tick {k}: {", ".join(late)} did not receive every input it '
                                'needs (an algorithm input that no node of the twin publishes?)')
            if t_ns % self.graph_period_ns == 0:
                self._sync_graph(k)
            self.recorder.tick_done()
            if on_tick is not None:
                on_tick(k, self)
        if k >= 0 and (k * self.period_ns) % self.graph_period_ns:
            self._sync_graph(k)         # a last turn at the end of the run (or at a stop)
        if self.clock_pub is not None and self._clock_wanted:
            # the followers' last tick waits for the last /clock: see it delivered before the
            # publisher goes (bounded: a follower that has gone acknowledges nothing)
            self.clock_pub.wait_for_all_acked(Duration(seconds=CLOCK_ACK_S))
        wall = time.perf_counter() - wall
        result = TwinResult(valve_model=self.valve_model, scenario=self.scenario,
                            params=self.params, control_period=self.control_period,
                            ticks=k + 1, wall_s=wall, interrupted=k < n_ticks,
                            simulated_s=min(k + 1, n_ticks) * self.period_ns * 1e-9,
                            bag=self.writer.dir if self.writer else None,
                            messages=self.recorder.count,
                            verdicts=[verdict(n) for n in self.observers])
        if self.recorder.keep_values:
            result.signals = self._signals()
        return result

    def _fault_ticks(self) -> dict[int, list]:
        """Scheduled fault events by the first tick starting at or after their time."""
        out: dict[int, list] = {}
        for e in self.scenario.fault_events(self.params):
            k = -(-int(round(e.at * 1e9)) // self.period_ns)
            out.setdefault(k, []).append(e)
        return out

    def _inject(self, events: list, t_ns: int) -> None:
        """Apply fault events as ``ros2 param set`` would, on every node of the actuator that
        reads the parameter (the ECU's GAP, CorM; the plant's everything else) -- never on the
        monitor, which models the nominal actuator."""
        for node in self.actuator:
            mine = [e for e in events if e.param in node.physical]
            if not mine:
                continue
            # the tick's events at once, validated as one state (as simulate applies them): a
            # dynamic friction beyond the static one raises FSJ with FDJ in one event pair,
            # and FDJ alone would be refused (FDJ > FSJ)
            result = node.set_parameters_atomically(
                [_ros_param_value(e.param, e.value) for e in mine])
            labels = ', '.join(dict.fromkeys(e.label for e in mine))
            if not result.successful:
                raise TwinError(f'fault {labels} at {t_ns * 1e-9:.3f} s refused by '
                                f'{node.get_name()}: {result.reason}')
            node.get_logger().info(f'fault injected at {t_ns * 1e-9:.3f} s: {labels}')
        unread = [e.label for e in events
                  if not any(e.param in n.physical for n in self.actuator)]
        if unread:
            raise TwinError(f'fault {unread[0]} at {t_ns * 1e-9:.3f} s: no node of the twin '
                            'reads its parameter')

    def _pace(self, due: float) -> None:
        """Paced: wait until the wall clock reaches ``due`` (perf_counter seconds), in slices,
        so that a stop request is seen within one."""
        while not self.stop_requested:
            ahead = due - time.perf_counter()
            if ahead <= 0:
                return
            time.sleep(min(ahead, PACE_SLICE_S))

    def _wait_for_followers(self) -> None:
        """The owner: wait (until stopped) for ``followers`` twins following /clock, each
        known by its ``twin_clock`` node in a namespace other than this twin's."""
        said = False
        while not self.stop_requested:
            found = {i.node_namespace for i in self.clock.get_subscriptions_info_by_topic(
                '/clock') if i.node_name == 'twin_clock'} - {self.namespace or '/'}
            if len(found) >= self.followers:
                return
            if not said:
                said = True
                self.clock.get_logger().info(
                    f'waiting for {self.followers} twin(s) following /clock '
                    f'({len(found)} on the graph)')
            time.sleep(PACE_SLICE_S)

    def _wait_for_clock(self, t_ns: int) -> None:
        """Following: let the executor take what arrives -- the owner's /clock among it --
        until simulated time has reached ``t_ns``. Said once when the owner is slow to come;
        the run stops (a readable bag) when an owner that was there leaves."""
        start = time.perf_counter()
        said = False
        checked = start
        while self._owner_ns < t_ns and not self.stop_requested:
            self.executor.spin_once(timeout_sec=PACE_SLICE_S)
            now = time.perf_counter()
            if now - checked < OWNER_CHECK_S:
                continue
            checked = now
            owners = self.clock.count_publishers('/clock')
            if owners == 0 and self._owner_ns >= 0:
                self.clock.get_logger().warning(
                    f'the /clock owner left at {self._owner_ns * 1e-9:.3f} s of simulated '
                    'time: stopping here')
                self.stop_requested = True
            elif not said:
                said = True
                self.clock.get_logger().info(
                    f'waiting for /clock to reach {t_ns * 1e-9:.3f} s (this twin follows '
                    f'the clock owner; {owners} publisher(s) of /clock seen)')

    def _sync_graph(self, k: int) -> None:
        """Every graph period: note which topics have DDS subscribers, and let the executor
        handle everything that has arrived up to the last /clock published -- the nodes'
        /clock, parameter requests and their responses -- in one call.

        The twin's own subscription to /clock marks the turn's end: the executor delivers in
        arrival order, so once it has taken that message, all that arrived before has been
        handled. (One ``spin_once`` of the EventsExecutor costs ~100 us here, ready event or
        not, and waiting at every 10 ms /clock for its delivery to each node cost ~20 us per
        tick, more than the physics.)"""
        for n in self.nodes:
            if isinstance(n, TwinNode):
                n.refresh_subscribers()
        # the twin's own /clock subscribers: every node's time source, and _on_clock
        if self.clock_pub is not None:
            self._clock_wanted = (self.clock_pub.get_subscription_count()
                                  > len(self.nodes) + 1)
        self._warn_foreign_publishers()
        if self.follow:
            # no /clock of our own: the turn ends at a message to itself sent now, queued
            # behind everything that has arrived
            self._turn = Future()
            self._turn_pub.publish(Empty())
            self.executor.spin_until_future_complete(self._turn, timeout_sec=TICK_DEADLINE_S)
            if not self._turn.done():
                raise TwinError(f'tick {k}: the executor did not take its turn within '
                                f'{TICK_DEADLINE_S} s')
            self._turn = None
            return
        if self._clock_ns == self._turned_ns:
            return                      # that /clock was taken at the previous turn
        self._turn = Future()
        self.executor.spin_until_future_complete(self._turn, timeout_sec=TICK_DEADLINE_S)
        if not self._turn.done():
            raise TwinError(f'tick {k}: /clock at {self._clock_ns * 1e-9:.3f} s was not '
                            f'delivered within {TICK_DEADLINE_S} s')
        self._turn = None
        self._turned_ns = self._clock_ns

    def _on_clock(self, msg: Clock) -> None:
        """The twin's own /clock subscription: it ends a turn (:meth:`_sync_graph`); following,
        it is the owner's time."""
        t_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if self.follow:
            self._owner_ns = max(self._owner_ns, t_ns)
        elif self._turn is not None and t_ns >= self._clock_ns and not self._turn.done():
            self._turn.set_result(t_ns)

    def _on_turn(self, _msg: Empty) -> None:
        if self._turn is not None and not self._turn.done():
            self._turn.set_result(True)

    def _warn_foreign_publishers(self) -> None:
        """Another graph on the same domain publishing the twin's topics cannot change the run
        (its nodes take their inputs in process) but mixes both on the topics: said once."""
        if self._warned_foreign:
            return
        for topic in self.bus.routes:
            if self.clock.count_publishers(topic) > 1:
                self._warned_foreign = True
                self.clock.get_logger().warning(
                    f'another node publishes /{topic} on ROS_DOMAIN_ID='
                    f'{os.environ.get("ROS_DOMAIN_ID", "0")}: this run is unaffected, but '
                    'subscribers see both graphs; give each run its own domain')
                return

    def _signals(self) -> dict[str, np.ndarray]:
        """The 1 ms rows of ``simulate``'s CSV from the recorded messages: the same builder the
        bag reader uses (:func:`~..bag.table.signal_table`)."""
        series = {}
        for topic in self.recorder.float_topics:
            times, values = self.recorder.values(topic)
            if times:
                series[f'/{topic}'] = (np.asarray(times, dtype=np.int64), np.asarray(values))
        return signal_table(series)

    def close(self) -> None:
        """Finalize the bag, destroy the nodes, shut the context down; safe to call twice."""
        if getattr(self, 'writer', None) is not None:
            if getattr(self, 'recorder', None) is not None:
                self.recorder.flush()
            self.writer.close()
        if getattr(self, 'live', None) is not None:
            self.live.close()
            self.live = None
        ex = getattr(self, 'executor', None)
        if ex is not None:
            ex.shutdown()
            self.executor = None
        for n in self.nodes:
            n.destroy_node()
        self.nodes = []
        if self._own_context:
            rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'Twin':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _absolute_namespace(namespace: str) -> str:
    """'left' or '/left' -> '/left', checked as ROS checks a namespace (one line otherwise)."""
    ns = '/' + namespace.strip('/')
    try:
        validate_namespace(ns)
    except InvalidNamespaceException as exc:
        raise TwinError(f'namespace {namespace!r}: {" ".join(str(exc).split())[:200]}; '
                        'expected names of letters, digits and _ separated by /') from None
    return ns


def _scenario_label(spec: Any, scenario: Scenario) -> str:
    """What the schedule nodes' ``scenario`` parameter says: the name or file the twin was
    given, or the scenario's own name when it was given as data."""
    if isinstance(spec, (str, Path)):
        return str(spec)
    return scenario.name


def _ros_param(name: str, params: EhaParams) -> Parameter:
    """A node's ROS parameter for ``params``' value; a derived parameter left to its
    derivation is 0.0, as the nodes declare it (so a fault on CLk still re-derives C4_alpha)."""
    value = getattr(params, name)
    return _ros_param_value(name, 0.0 if value is None else value)


def _ros_param_value(name: str, value: Any) -> Parameter:
    if isinstance(value, bool):
        return Parameter(name, Parameter.Type.BOOL, value)
    if isinstance(value, int):
        return Parameter(name, Parameter.Type.INTEGER, value)
    return Parameter(name, Parameter.Type.DOUBLE, float(value))


def run_twin(valve_model: str, scenario: str | Path | Scenario | Mapping = 'paper',
             overrides: Mapping[str, Any] | None = None, *, control_period: float = 1e-3,
             bag: str | Path | None = None, handle_signals: bool = True,
             on_tick: Callable[[int, 'Twin'], None] | None = None, **kwargs) -> TwinResult:
    """Build, run and close a twin; SIGINT/SIGTERM finish the bag and return early."""
    twin = Twin(valve_model, scenario, overrides, control_period=control_period, bag=bag,
                **kwargs)
    old = {}
    if handle_signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, twin.request_stop)
    try:
        return twin.run(on_tick)
    finally:
        twin.close()
        for sig, handler in old.items():
            signal.signal(sig, handler)
