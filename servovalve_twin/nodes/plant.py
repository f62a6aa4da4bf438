"""The plant node: the EHA (servovalve mechanics, selectable fluid model, jack) integrated with
the physics layer's :class:`~servovalve_twin.physics.simulate.EhaPlant`."""

from __future__ import annotations

import json
from typing import Any, Sequence

from rcl_interfaces.msg import ParameterDescriptor

from ..bag.cdr import encode_jack_state
from ..errors import ModelError
from ..physics.params import EhaParams
from ..physics.simulate import EhaPlant, steps_per
from ..physics.valves import VALVE_MODEL_NAMES, get_valve_model
from .base import TwinNode
from .process import spin_standalone
from .topics import joint_state

STATE_TOPICS = ('xs', 'xj', 'dxj')


class Plant(TwinNode):
    """The EHA plant.

    Subscribes: ``cor`` (std_msgs/Float64, A), ``fr`` (std_msgs/Float64, N), ``psr``
    (std_msgs/Float64, Pa).
    Publishes: ``xs``, ``xj`` (std_msgs/Float64, m), ``dxj`` (m/s), ``p12`` (Pa), ``qj``
    (m^3/s), ``p1``, ``p2`` (Pa, models with port pressures only: HD), ``joint_states``
    (sensor_msgs/JointState, joint ``jack``: position XJ [m], velocity DXJ [m/s], effort
    AJ*P12 [N]).
    Parameters: ``valve_model`` (string, one of the registry; switchable during a run: the
    mechanical state is kept), ``control_period`` (double, s, read-only), ``sensors`` (string,
    read-only: the unit's sensors as a JSON/YAML mapping of the scenario's ``sensors`` schema,
    ``physics/sensors.py``; '' = ideal: XS, XJ, DXJ, P12, P1, P2 and the joint state are then
    what the sensors read, and the ECU closes its loop on that XJ), and every physical
    parameter the plant reads (all but the ECU's GAP and CorM) with its unit and range (``DT``
    read-only).

    Per control period starting at t: the state at t (XS, XJ, DXJ) is published; with the
    inputs in force from t (Cor, FR, PSR; alone: the latest received, by default 0 A, 0 N and
    PSRN), P12 and QJ at t are published with the joint state, and the EHA is integrated to
    t + control_period in DT sub-steps.
    """

    subsystem = 'plant'

    def __init__(self, **kwargs):
        super().__init__('plant', **kwargs)
        self.declare_parameter('valve_model', 'C2', ParameterDescriptor(
            description='servovalve fluid-dynamic model',
            additional_constraints='one of: ' + ', '.join(VALVE_MODEL_NAMES)))
        self.declare_parameter('sensors', '', ParameterDescriptor(
            description="the unit's sensors: a JSON/YAML mapping {seed: N, SIGNAL: {noise, "
                        "bias, drift, quantisation, period}}; empty: ideal sensors",
            read_only=True))
        self.plant = EhaPlant(self.get_parameter('valve_model').value, self.params)
        self.n_sub = steps_per(self.period, self.params, 'control_period')
        self.plant.set_sensors(parse_sensors(self.get_parameter('sensors').value), self.period)
        self._joint = None                 # the JointState message, refilled every tick
        self.add_publishers(STATE_TOPICS + ('p12', 'qj', 'joint_states'))
        self._advertise_ports()
        # alone: Cor 0 A, FR 0 N and PSR = PSRN until the first messages arrive
        self.start_inputs({'cor': 0.0, 'fr': 0.0, 'psr': self.params.PSRN})
        self.start()

    # -- parameters ---------------------------------------------------------------------
    def check_parameters(self, changes: dict[str, Any]) -> None:
        if 'valve_model' in changes:
            get_valve_model(changes['valve_model'])
        super().check_parameters(changes)

    def on_params(self, params: EhaParams) -> None:
        self.plant.set_params(params)

    def apply_parameters(self, changes: dict[str, Any]) -> None:
        super().apply_parameters(changes)
        name = changes.get('valve_model')
        if name is not None and name != self.plant.model.name:
            old = self.plant.model.name
            self.plant.set_valve_model(name)
            self._advertise_ports()
            self.get_logger().info(f'valve model {old} -> {name}; mechanical state kept'
                                   f' (XJ = {self.plant.xj:.6g} m)')

    def _advertise_ports(self) -> None:
        """/p1 and /p2 exist while a model with port pressures (HD) is in force."""
        if self.plant.model.has_ports:
            self.add_publishers([t for t in ('p1', 'p2') if t not in self.pubs])
        else:
            for t in ('p1', 'p2'):
                pub = self.pubs.pop(t, None)
                if pub is not None:
                    self.destroy_publisher(pub)

    # -- ticks --------------------------------------------------------------------------
    def begin_tick(self, t_ns: int, n_sub: int) -> None:
        """Lockstep: publish the state at t and wait for the tick's inputs."""
        self._publish_state(t_ns)
        super().begin_tick(t_ns, n_sub)

    def _publish_state(self, t_ns: int) -> None:
        """XS, XJ, DXJ at t as the sensors read them (the truth without sensors)."""
        if self.plant.sensors is None:
            self._state = (self.plant.xs, self.plant.xj, self.plant.dxj)
        else:
            self._state = tuple(self.plant.sense_state(t_ns).tolist())
        self.emit_value('xs', self._state[0])
        self.emit_value('xj', self._state[1])
        self.emit_value('dxj', self._state[2])

    def step(self, tick: tuple[int, int], v: dict[str, float]) -> None:
        t_ns, n_sub = tick
        self._advance(t_ns, n_sub, v['cor'], v['fr'], v['psr'])

    def _advance(self, t_ns: int, n_sub: int, cor: float, fr: float, psr: float) -> None:
        _, xj, dxj = self._state            # as published at the tick's start
        p12, qj, p1, p2 = self.plant.tick(cor, fr, psr, n_sub).tolist()
        if self.plant.sensors is not None:
            p12, p1, p2 = self.plant.sense_valve(t_ns).tolist()
        self.emit_value('p12', p12)
        self.emit_value('qj', qj)
        if self.plant.model.has_ports:
            self.emit_value('p1', p1)
            self.emit_value('p2', p2)
        force = self.plant.params.AJ * p12
        if self.tap_bytes is not None and not self.wanted('joint_states'):
            # the twin records it and nothing on DDS subscribes: encode it, build no message
            self.tap_bytes('joint_states', encode_jack_state(t_ns, xj, dxj, force))
            return
        self._joint = joint_state(t_ns, xj, dxj, force, self._joint)
        self.emit('joint_states', self._joint)

    def on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        self._count_overruns(now)
        self._publish_state(now)
        try:
            v = self.io.latest
            self._advance(now, self.n_sub, v['cor'], v['fr'], v['psr'])
        except ModelError as exc:
            self.get_logger().error(f'tick skipped: {exc}', throttle_duration_sec=1.0)


    def _count_overruns(self, now_ns: int) -> None:
        """Alone, each timer call integrates one control period: a call that comes late (a
        machine too slow for the 1 kHz timer) leaves the plant behind its clock. Such missed
        periods are counted and reported (every 5 s), not hidden."""
        last = getattr(self, '_last_timer_ns', None)
        self._last_timer_ns = now_ns
        period_ns = int(round(self.period * 1e9))
        if last is None or now_ns <= last:
            return
        missed = (now_ns - last) // period_ns - 1
        if missed > 0:
            self.overruns = getattr(self, 'overruns', 0) + int(missed)
            self.get_logger().warning(
                f'{self.overruns} control periods missed so far: the plant runs slower than its '
                'clock (the machine cannot keep the timer); simulated time lags',
                throttle_duration_sec=5.0)


def parse_sensors(text: str):
    """The ``sensors`` parameter: '' (ideal sensors) or a JSON/YAML mapping."""
    from ..physics.sensors import sensors_from_dict
    if not text.strip():
        return None
    from ..config import load_yaml_text
    # the scenario files' loader: no aliases (a live parameter is as hostile as a file), and
    # nesting or a huge number refused in one line
    return sensors_from_dict(load_yaml_text(text, 'parameter sensors'), 'parameter sensors')


def sensors_text(sensors) -> str:
    """The ``sensors`` parameter's value for ``sensors`` (None: '')."""
    return json.dumps(sensors.to_dict()) if sensors else ''


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Plant, args)
