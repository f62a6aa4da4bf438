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

import os
import signal
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from .. import stopping
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
from ..nodes.topics import TOPICS, type_name
from ..nodes.ecu import Ecu
from ..nodes.monitor import MONITOR_TOPICS, Monitor
from ..nodes.plant import Plant, sensors_text
from ..nodes.sources import CommandGenerator, LoadSupply
from ..physics.params import EhaParams
from ..physics.simulate import OUTPUT_PERIOD_NS, effective_params, steps_per
from ..physics.valves import get_monitor_model, get_valve_model
from ..prognostics.algorithm import load_algorithm
from ..prognostics.watchdog import Watchdog, exits_refused, in_step_beats
from .graph import EXECUTORS, GraphClock, OwnerLeft, absolute_namespace
from .config import (TwinConfig, TwinResult, check_clock_options, ros_param, ros_param_value,
                     scenario_label)

#: how often (simulated time) the executor gets a turn: node clocks and parameter requests
#: follow at this pace, external subscribers are noticed at it
GRAPH_PERIOD_NS = 100_000_000
#: ticks of the input schedule evaluated at a time (the lists cost ~100 bytes a tick)
SCHEDULE_TICKS = 1 << 14




class Twin:
    """The in-process graph. Create, :meth:`run`, :meth:`close` (or use as a context manager).

    :param config: what the run is made of (:class:`~.config.TwinConfig`: the valve model, the
        scenario -- a name, a file, or in Python a :class:`~..physics.scenario.Scenario` or a
        mapping --, periods, clock mode, namespace, monitor, algorithms, recording, live view),
        the same one the ``run`` command and the ``twin`` executable build from their options
        and ROS parameters, so that a run from Python is the command's run (what each field
        does: its docstring). It records into ``config.bag_dir(...)``: ``record=False`` for none
    :param overrides: physical parameters over the design's (``{'M': 900.0}``)
    :param base_params: the design they apply to (default: the documented one; a replayed
        bag's)
    :param keep_values: keep the Float64 values to build the 1 ms signal table (``signals``)
    :param on_flush: called with the simulated time each time the bag is flushed
    :param context: a private rclpy context (tests) or None for a new one
    :param args: ROS arguments of the context (``--ros-args -r __ns:=/left``; without them,
        none: rcl would otherwise read the caller's own command line)
    :param domain_id: the DDS domain of a new context
    :param executor: 'events' (rclpy's EventsExecutor) or 'single' (SingleThreadedExecutor)
    """

    def __init__(self, config: TwinConfig, overrides: Mapping[str, Any] | None = None, *,
                 base_params: EhaParams | None = None, keep_values: bool = True,
                 on_flush: Callable[[float], None] | None = None,
                 context: Context | None = None, args: Sequence[str] | None = None,
                 domain_id: int | None = None, executor: str = 'events'):
        if not isinstance(config, TwinConfig):
            raise TwinError(f'Twin takes a TwinConfig, got {type(config).__name__}')
        self.config = config
        valve_model, monitor = config.valve_model, config.monitor or None
        get_valve_model(valve_model)
        check_clock_options(config.clock, config.real_time_factor, config.followers)
        if executor not in EXECUTORS:
            raise TwinError(f'unknown executor {executor!r}; expected one of '
                            f'{sorted(EXECUTORS)}')
        if monitor is not None:
            get_monitor_model(monitor)
        self.scenario = load_scenario(config.scenario)
        if config.sensor_seed is not None:
            # the plant node and the bag's provenance take the sensors from the scenario
            self.scenario = self.scenario.with_sensor_seed(config.sensor_seed)
        self.params = effective_params(self.scenario, overrides, base_params)
        self.valve_model = valve_model
        self.control_period = config.control_period
        self._check_periods(config.control_period, config.clock_period)
        self._own_context = context is None
        self.context = context or Context()
        if not self.context.ok():
            # without ``args``, none: rcl would otherwise read sys.argv, the caller's own
            # command line, for rules of its own
            rclpy.init(args=list(args) if args is not None else [], context=self.context,
                       domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.writer = None
        self.live = None
        self.nodes: list[Node] = []
        self.stop_requested = False
        self._warned_foreign = False
        try:
            types = self._make_nodes(config.scenario, monitor, config.algorithms(),
                                     config.namespace or None)
            self.sim = GraphClock(self.clock, follow=config.clock == 'follow',
                                  real_time_factor=config.real_time_factor,
                                  followers=config.followers, namespace=self.namespace,
                                  stopped=lambda: self.stop_requested)
            self._make_recording(types, config.bag_dir(self.scenario.name), config.overwrite,
                                 keep_values, on_flush, config.foxglove)
            self.executor = EXECUTORS[executor](context=self.context)
            for n in self.nodes:
                self.executor.add_node(n)
            self.sim.executor = self.executor
        except BaseException:          # a refusal, a failure or Ctrl-C during start-up
            if self.writer is not None:
                self.writer.abort()
                self.writer = None
            self.close()
            raise

    def _check_periods(self, control_period: float, clock_period: float) -> None:
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

    def _make_nodes(self, scenario_spec: Any, monitor: str | None, algorithms: Sequence[Any],
                    namespace: str | None) -> dict[str, str]:
        """The actuator's nodes, the monitor and algorithm nodes, the clock node; returns the
        recorded topics' types by graph name."""
        sim = Parameter('use_sim_time', Parameter.Type.BOOL, True)
        period = Parameter('control_period', Parameter.Type.DOUBLE, float(self.control_period))
        # the schedule nodes own the scenario loaded here, once; their parameter names it
        scn = Parameter('scenario', Parameter.Type.STRING,
                        scenario_label(scenario_spec, self.scenario))
        self.bus = LocalBus()
        kw = dict(context=self.context, lockstep=True, bus=self.bus)
        if namespace:
            kw['namespace'] = absolute_namespace(namespace)

        def physical(cls) -> list[Parameter]:
            return [sim, period] + [ros_param(n, self.params) for n in cls.declared_physical()]
        self.command_generator = CommandGenerator(scenario=self.scenario, **kw,
                                                  parameter_overrides=[sim, period, scn])
        self.load_supply = LoadSupply(scenario=self.scenario, **kw,
                                      parameter_overrides=[sim, period, scn])
        self.ecu = Ecu(params=self.params, **kw, parameter_overrides=physical(Ecu))
        self.plant = Plant(params=self.params, **kw, parameter_overrides=physical(Plant) + [
            Parameter('valve_model', Parameter.Type.STRING, self.valve_model),
            Parameter('sensors', Parameter.Type.STRING, sensors_text(self.scenario.sensors))])
        self.clock = Node('twin_clock', context=self.context, parameter_overrides=[sim],
                          **({'namespace': kw['namespace']} if namespace else {}))
        #: where the actuator's topics live: '' or '/left' (an explicit namespace or a __ns
        #: remap among the context's arguments)
        self.namespace = self.plant.get_namespace().rstrip('/')
        self.nodes = [self.command_generator, self.load_supply, self.ecu, self.plant,
                      self.clock]
        topics = dict(TOPICS)
        self.monitor = None
        if monitor is not None:
            # the monitor models the whole actuator with the nominal (pre-fault) values
            self.monitor = Monitor(params=self.params, **kw, parameter_overrides=physical(
                Monitor) + [Parameter('monitor_model', Parameter.Type.STRING, monitor)])
            topics.update(MONITOR_TOPICS)
        # the user's algorithms: (class path or class, parameters) or instances
        self.algorithms = []
        for i, spec in enumerate(algorithms):
            cls, aparams = spec if isinstance(spec, tuple) else (spec, None)
            # (an import that blocks held run for ever)
            with Watchdog(lambda: 0, f'algorithm {cls!r}: its import'):
                alg = load_algorithm(cls, aparams)
            taken = sorted(t for t in algorithm_topics(alg) if t in topics and t != 'diagnostics')
            if taken:
                # two publishers of one signal: the bag would hold two values per tick
                raise TwinError(f'algorithm {alg.title} publishes {taken[0]}, which another node '
                                'of the twin publishes already: give it another topic_prefix')
            name = getattr(alg, 'node_name', None) or (
                'algorithm' if i == 0 else f'algorithm_{i + 1}')
            with Watchdog(lambda: 0, f'algorithm {alg.title}: its setup'):
                self.algorithms.append(AlgorithmNode(alg, name=name, params=self.params, **kw,
                                                     parameter_overrides=[sim, period]))
            topics.update(algorithm_topics(alg))
        #: the nodes that complete a tick after the plant (they read its outputs)
        self.observers = ([self.monitor] if self.monitor else []) + self.algorithms
        self.nodes += self.observers
        #: the actuator's nodes: a scheduled fault goes to every one that reads its parameter
        self.actuator = [self.ecu, self.plant]
        types = {f'{self.namespace}/{t}': type_name(spec[0]) for t, spec in topics.items()}
        types['/clock'] = 'rosgraph_msgs/msg/Clock'
        return types

    def _make_recording(self, types: dict[str, str], bag: str | Path | None, overwrite: bool,
                        keep_values: bool, on_flush: Callable[[float], None] | None,
                        foxglove: int | None) -> None:
        """The recorder every node publishes through, the bag (opened once everything else
        has been accepted: a refused start-up leaves no bag behind) and the live view."""
        if bag is not None:
            self.writer = BagWriter(bag, overwrite=overwrite, flush_every_ns=None)
        self.recorder = Recorder(self.writer, types, keep_values=keep_values,
                                 namespace=self.namespace)
        if self.writer is not None:     # after the topics, as the bag's records always were
            self.writer.add_metadata(PROVENANCE, Provenance.build(
                self.valve_model, self.scenario, self.params, self.control_period,
                namespace=self.namespace).to_record())
        self.recorder.on_flush = on_flush
        if foxglove is not None:        # serve every recorded message to the Foxglove app
            from ..nodes.live import FoxgloveLive
            self.live = FoxgloveLive(types, port=foxglove)
            self.recorder.sinks.append(self.live.log)
        for n in self.nodes:
            if n is not self.clock:
                n.tap = self.recorder.record
                n.tap_value = self.recorder.record_value
                n.tap_bytes = self.recorder.record_bytes

    def request_stop(self, *_: Any) -> None:
        """Stop at the next tick boundary (signal handlers call this)."""
        self.stop_requested = True

    def run(self, on_tick: Callable[[int, 'Twin'], None] | None = None) -> TwinResult:
        """Run the scenario; ``on_tick(k, twin)`` is called after each tick (faults, tests).
        A user's algorithm runs under a :class:`~..prognostics.watchdog.Watchdog` (a step
        that makes no progress for STEP_LIMIT_S ends the run with one line, the bag closed)
        and may not end the process (``os._exit``: the bag was left without its metadata)."""
        if not self.algorithms:
            return self._run(on_tick)
        titles = ', '.join(n.runner.alg.title for n in self.algorithms)
        with Watchdog(in_step_beats([n.runner for n in self.algorithms]),
                      f'algorithm {titles}'), exits_refused(f'algorithm {titles}'):
            return self._run(on_tick)

    def _run(self, on_tick: Callable[[int, 'Twin'], None] | None) -> TwinResult:
        n_ticks = self.scenario.duration_ns // self.period_ns
        faults = self._fault_ticks()
        self.sim.wait_for_followers()
        wall = time.perf_counter()
        k = -1
        for k in range(n_ticks + 1):
            t_ns = k * self.period_ns
            try:
                self.sim.before(t_ns, wall, t_ns % self.clock_period_ns == 0)
            except OwnerLeft:
                self.stop_requested = True
            if self.stop_requested:
                k -= 1
                break
            self.recorder.now_ns = t_ns
            if t_ns % self.clock_period_ns == 0:
                msg = clock_msg(t_ns)
                self.recorder.record('/clock', msg)
                self.sim.publish(t_ns, msg, t_ns % self.graph_period_ns == 0)
            if k in faults:
                self._inject(faults[k], t_ns)
            if k % SCHEDULE_TICKS == 0:
                # the schedule, evaluated a stretch of ticks at a time: the values simulate()
                # samples, in memory that does not grow with the run
                at = np.arange(k, min(k + SCHEDULE_TICKS, n_ticks + 1), dtype=np.int64)
                com, fr, psr = (a.tolist() for a in self.scenario.inputs(at * self.period_ns))
            j = k % SCHEDULE_TICKS
            n_sub = self.n_sub if k < n_ticks else 0      # the end instant: evaluate only
            for node in self.observers:
                node.begin_tick(t_ns, n_sub)
            self.plant.begin_tick(t_ns, n_sub)
            self.command_generator.publish_values({'com': com[j]})
            self.load_supply.publish_values({'fr': fr[j], 'psr': psr[j]})
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
        self.sim.finish()
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
                [ros_param_value(e.param, e.value) for e in mine])
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

    def _sync_graph(self, k: int) -> None:
        """Every graph period: note which topics have DDS subscribers, then give the executor
        its turn (:meth:`GraphClock.take_turn`): the nodes' /clock, parameter requests and
        their responses. (One ``spin_once`` of the EventsExecutor costs ~100 us here, ready
        event or not, and waiting at every 10 ms /clock for its delivery to each node cost
        ~20 us per tick, more than the physics.)"""
        for n in self.nodes:
            if isinstance(n, TwinNode):
                n.refresh_subscribers()
        # the twin's own /clock subscribers: every node's time source, and the GraphClock's
        self.sim.refresh(len(self.nodes) + 1)
        self._warn_foreign_publishers()
        self.sim.take_turn(k)

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


def run_twin(config: TwinConfig, overrides: Mapping[str, Any] | None = None, *,
             handle_signals: bool = True, on_tick: Callable[[int, 'Twin'], None] | None = None,
             **kwargs) -> TwinResult:
    """Build, run and close a twin (:class:`Twin`'s parameters); SIGINT/SIGTERM finish the bag
    and return early."""
    twin = Twin(config, overrides, **kwargs)
    old = stopping.handle(twin.request_stop) if handle_signals else {}
    try:
        return twin.run(on_tick)
    finally:
        twin.close()
        for sig, handler in old.items():
            signal.signal(sig, handler)
