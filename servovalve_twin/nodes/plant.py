"""The plant node: the EHA (servovalve mechanics, selectable fluid model, jack) integrated with
the physics layer's :class:`~servovalve_twin.physics.simulate.EhaPlant`."""

from __future__ import annotations

from typing import Sequence

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from ..errors import ModelError
from ..physics.simulate import EhaPlant, steps_per
from ..physics.valves import VALVE_MODEL_NAMES, get_valve_model
from .common import (QOS, LockstepInputs, TwinNode, declare_physical, joint_state,
                     physical_from_node, spin_standalone, validation_result, with_ros_values)

STATE_TOPICS = ('xs', 'xj', 'dxj')
VALVE_TOPICS = ('p12', 'qj', 'p1', 'p2')


class Plant(TwinNode):
    """The EHA plant.

    Subscribes: ``cor`` (std_msgs/Float64, A), ``fr`` (std_msgs/Float64, N), ``psr``
    (std_msgs/Float64, Pa).
    Publishes: ``xs``, ``xj`` (std_msgs/Float64, m), ``dxj`` (m/s), ``p12`` (Pa), ``qj``
    (m^3/s), ``p1``, ``p2`` (Pa, models with port pressures only: HD), ``joint_states``
    (sensor_msgs/JointState, joint ``jack``: position XJ [m], velocity DXJ [m/s], effort
    AJ*P12 [N]).
    Parameters: ``valve_model`` (string, one of the registry; switchable during a run: the
    mechanical state is kept), ``control_period`` (double, s, read-only), and every physical
    parameter of ``config/eha.yaml`` with its unit and range (``DT`` read-only).

    Per control period starting at t: the state at t (XS, XJ, DXJ) is published; with the
    inputs in force from t (Cor, FR, PSR; alone: the latest received, by default 0 A, 0 N and
    PSRN), P12 and QJ at t are published with the joint state, and the EHA is integrated to
    t + control_period in DT sub-steps.
    """

    def __init__(self, *, lockstep: bool = False, params=None, **kwargs):
        super().__init__('plant', **kwargs)
        self.declare_parameter('valve_model', 'C2', ParameterDescriptor(
            description='servovalve fluid-dynamic model',
            additional_constraints='one of: ' + ', '.join(VALVE_MODEL_NAMES)))
        self.declare_parameter('control_period', 0.001, ParameterDescriptor(
            description='control period [s]: inputs are held over it', read_only=True))
        declare_physical(self)
        base = physical_from_node(self) if params is None else params
        self.plant = EhaPlant(self.get_parameter('valve_model').value, base)
        self.n_sub = steps_per(self.get_parameter('control_period').value, base,
                               'control_period')
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)
        # alone: Cor 0 A, FR 0 N and PSR = PSRN until the first messages arrive
        self.io = LockstepInputs(self, {'cor': 0.0, 'fr': 0.0, 'psr': base.PSRN},
                                 lockstep=lockstep)
        self._joint = None                 # the JointState message, refilled every tick
        self.done = -1                     # ticks completed (lockstep)
        self.add_publishers(STATE_TOPICS + VALVE_TOPICS + ('joint_states',))
        for name in self.io.latest:
            self.create_subscription(Float64, name, lambda m, n=name: self._on_input(n, m), QOS)
        if not lockstep:
            self.create_timer(self.get_parameter('control_period').value, self._on_timer)

    # -- parameters ---------------------------------------------------------------------
    def _validate(self, params: list[Parameter]):
        def check():
            for p in params:
                if p.name == 'valve_model':
                    get_valve_model(p.value)
            with_ros_values(self.plant.params, {p.name: p.value for p in params})
        return validation_result(check)

    def _apply(self, params: list[Parameter]) -> None:
        changes = {p.name: p.value for p in params if p.name != 'valve_model'}
        if changes:
            self.plant.set_params(with_ros_values(self.plant.params, changes))
        for p in params:
            if p.name == 'valve_model' and p.value != self.plant.model.name:
                old = self.plant.model.name
                self.plant.set_valve_model(p.value)
                self.get_logger().info(f'valve model {old} -> {p.value}; mechanical state kept'
                                       f' (XJ = {self.plant.xj:.6g} m)')

    # -- inputs -------------------------------------------------------------------------
    def _on_input(self, name: str, msg: Float64) -> None:
        self.io.push(name, msg)
        self._try_tick()

    # -- ticks --------------------------------------------------------------------------
    def begin_tick(self, t_ns: int, integrate: bool = True) -> None:
        """Lockstep: publish the state at t and wait for the tick's inputs; ``integrate``
        False evaluates P12 at t without advancing (the run's end instant)."""
        self.io.begin(t_ns, self.n_sub if integrate else 0)
        self._publish_state()
        self._try_tick()

    def _publish_state(self) -> None:
        self.emit_value('xs', self.plant.xs)
        self.emit_value('xj', self.plant.xj)
        self.emit_value('dxj', self.plant.dxj)

    def _try_tick(self) -> None:
        ready = self.io.pop() if self.io.lockstep else None
        if ready is not None:
            (t_ns, n_sub), v = ready
            self._advance(t_ns, n_sub, v['cor'], v['fr'], v['psr'])
            self.done += 1

    def _advance(self, t_ns: int, n_sub: int, cor: float, fr: float, psr: float) -> None:
        xj, dxj = self.plant.xj, self.plant.dxj
        p12, qj, p1, p2 = self.plant.tick(cor, fr, psr, n_sub)
        self.emit_value('p12', p12)
        self.emit_value('qj', qj)
        if self.plant.model.has_ports:
            self.emit_value('p1', p1)
            self.emit_value('p2', p2)
        self._joint = joint_state(t_ns, xj, dxj, self.plant.params.AJ * p12, self._joint)
        self.emit('joint_states', self._joint)

    def _on_timer(self) -> None:
        self._publish_state()
        try:
            v = self.io.latest
            self._advance(self.get_clock().now().nanoseconds, self.n_sub, v['cor'], v['fr'],
                          v['psr'])
        except ModelError as exc:
            self.get_logger().error(f'tick skipped: {exc}', throttle_duration_sec=1.0)

    def pending(self) -> int:
        return self.io.pending()


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Plant, args)

