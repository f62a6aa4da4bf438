"""The ECU node: the position loop Cor = sat(GAP*(Com - XJ), CorM)."""

from __future__ import annotations

from typing import Sequence

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from ..physics.simulate import EhaPlant
from .common import (QOS, LockstepInputs, TwinNode, declare_physical, physical_from_node,
                     spin_standalone, validation_result, with_ros_values)
from std_msgs.msg import Float64

ECU_PARAMS = ('GAP', 'CorM')


class Ecu(TwinNode):
    """Position loop of the EHA.

    Subscribes: ``com`` (std_msgs/Float64, m), ``xj`` (std_msgs/Float64, m).
    Publishes: ``cor`` (std_msgs/Float64, A).
    Parameters: ``GAP`` (double, A/m), ``CorM`` (double, A), ``control_period`` (double, s,
    read-only; alone only).

    Alone, a timer computes Cor every ``control_period`` from the latest Com and XJ (0 m until
    the first messages arrive). In the lockstep it computes once per tick, when that tick's
    Com and XJ have both arrived.
    """

    def __init__(self, *, lockstep: bool = False, **kwargs):
        super().__init__('ecu', **kwargs)
        declare_physical(self, ECU_PARAMS)
        self.declare_parameter('control_period', 0.001, ParameterDescriptor(
            description='control period [s] when running alone', read_only=True))
        # the control law is the physics layer's, evaluated by the same compiled function
        self.law = EhaPlant('C2', physical_from_node(self, ECU_PARAMS))
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)
        # alone: Com and XJ are 0 m until the first messages arrive
        self.io = LockstepInputs(self, {'com': 0.0, 'xj': 0.0}, lockstep=lockstep,
                                 ticked=False)
        self.add_publishers(['cor'])
        for name in self.io.latest:
            self.create_subscription(Float64, name, lambda m, n=name: self._on_input(n, m), QOS)
        if not lockstep:
            self.create_timer(self.get_parameter('control_period').value, self._on_timer)

    def _validate(self, params: list[Parameter]):
        return validation_result(lambda: with_ros_values(
            self.law.params, {p.name: p.value for p in params}))

    def _apply(self, params: list[Parameter]) -> None:
        self.law.set_params(with_ros_values(self.law.params, {p.name: p.value for p in params}))

    def _on_input(self, name: str, msg: Float64) -> None:
        self.io.push(name, msg)
        ready = self.io.pop() if self.io.lockstep else None
        if ready is not None:
            _, v = ready
            self.emit_value('cor', self.law.control(v['com'], v['xj']))

    def _on_timer(self) -> None:
        self.emit_value('cor', self.law.control(self.io.latest['com'], self.io.latest['xj']))

    def pending(self) -> int:
        return self.io.pending()


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Ecu, args)
