"""The ECU node: the position loop Cor = sat(GAP*(Com - XJ), CorM)."""

from __future__ import annotations

from collections import deque
from typing import Sequence

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from ..physics.simulate import EhaPlant
from .common import (QOS, TwinNode, declare_physical, finite_or_none, physical_from_node,
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
        self.lockstep = lockstep
        self.com = 0.0
        self.xj = 0.0
        self._com_q: deque[float] = deque()
        self._xj_q: deque[float] = deque()
        self.add_publishers(['cor'])
        self.create_subscription(Float64, 'com', self._on_com, QOS)
        self.create_subscription(Float64, 'xj', self._on_xj, QOS)
        if not lockstep:
            self.create_timer(self.get_parameter('control_period').value, self._on_timer)

    def _validate(self, params: list[Parameter]):
        return validation_result(lambda: with_ros_values(
            self.law.params, {p.name: p.value for p in params}))

    def _apply(self, params: list[Parameter]) -> None:
        self.law.set_params(with_ros_values(self.law.params, {p.name: p.value for p in params}))

    def _on_com(self, msg: Float64) -> None:
        v = finite_or_none(msg.data, 'Com', self)
        if v is None:
            return
        self.com = v
        if self.lockstep:
            self._com_q.append(v)
            self._try_tick()

    def _on_xj(self, msg: Float64) -> None:
        v = finite_or_none(msg.data, 'XJ', self)
        if v is None:
            return
        self.xj = v
        if self.lockstep:
            self._xj_q.append(v)
            self._try_tick()

    def _try_tick(self) -> None:
        if self._com_q and self._xj_q:
            self.emit_value('cor', self.law.control(self._com_q.popleft(), self._xj_q.popleft()))

    def _on_timer(self) -> None:
        self.emit_value('cor', self.law.control(self.com, self.xj))

    def pending(self) -> int:
        """Inputs waiting for their partner: more than one means a foreign publisher."""
        return max(len(self._com_q), len(self._xj_q))


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Ecu, args)
