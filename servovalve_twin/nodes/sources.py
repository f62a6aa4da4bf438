"""Schedule nodes: the command generator (Com) and the load / supply scheduler (FR, PSR).

Both read a scenario (:mod:`servovalve_twin.physics.scenario`) and publish its values at the
scenario time. Alone, a timer with period ``control_period`` drives them on the node clock (wall
time, or ``/clock`` when ``use_sim_time`` is true), scenario time counting from the first tick
with a valid time (with ``use_sim_time``, nothing is published before the first ``/clock``);
after the scenario's end the last values are held. Inside ``twin`` the orchestrator calls
:meth:`ScheduleSource.step` once per tick instead (no timer), which is what makes the lockstep
deterministic.
"""

from __future__ import annotations

from typing import Sequence

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from ..physics.scenario import Scenario, load_scenario
from .common import TwinNode, spin_standalone, validation_result


class ScheduleSource(TwinNode):
    """Base of the schedule nodes: scenario parameter, timer or lockstep, publishers."""

    signals: tuple[str, ...] = ()

    def __init__(self, name: str, *, lockstep: bool = False, **kwargs):
        super().__init__(name, **kwargs)
        self.declare_parameter('scenario', 'paper', ParameterDescriptor(
            description="built-in scenario name ('paper', 'defaults', ...) or a YAML file"))
        self.declare_parameter('control_period', 0.001, ParameterDescriptor(
            description='publication period [s] when running alone', read_only=True))
        self.scenario: Scenario = load_scenario(self.get_parameter('scenario').value)
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)
        self.add_publishers(self.signals)
        self._t0_ns: int | None = None
        if not lockstep:
            self.create_timer(self.get_parameter('control_period').value, self._on_timer)

    def _validate(self, params: list[Parameter]):
        for p in params:
            if p.name == 'scenario':
                return validation_result(lambda value=p.value: load_scenario(value))
        return validation_result(lambda: None)

    def _apply(self, params: list[Parameter]) -> None:
        for p in params:
            if p.name == 'scenario':
                self.scenario = load_scenario(p.value)
                self.get_logger().info(f'scenario {self.scenario.name!r} loaded')

    def values(self, t_ns: int) -> dict[str, float]:
        """The scenario's signals at scenario time ``t_ns``."""
        t = min(t_ns, self.scenario.duration_ns)
        return {s: getattr(self.scenario, s).value(t) for s in self.signals}

    def step(self, t_ns: int) -> None:
        """Publish the values at scenario time ``t_ns``."""
        self.publish_values(self.values(t_ns))

    def publish_values(self, values: dict[str, float]) -> None:
        """Publish given values (the lockstep evaluates the whole schedule up front)."""
        for s, v in values.items():
            self.emit_value(s, v)

    def _on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        if now == 0:
            return          # use_sim_time and no /clock received yet: time is not valid
        if self._t0_ns is None or now < self._t0_ns:     # first tick, or sim time reset
            self._t0_ns = now
        self.step(now - self._t0_ns)


class CommandGenerator(ScheduleSource):
    """Publishes the position command.

    Publishes: ``com`` (std_msgs/Float64, m).
    Parameters: ``scenario`` (string), ``control_period`` (double, s, read-only).
    """

    signals = ('com',)

    def __init__(self, **kwargs):
        super().__init__('command_generator', **kwargs)


class Scheduler(ScheduleSource):
    """Publishes the external load and the supply pressure.

    Publishes: ``fr`` (std_msgs/Float64, N, > 0 opposes +XJ), ``psr`` (std_msgs/Float64, Pa).
    Parameters: ``scenario`` (string), ``control_period`` (double, s, read-only).
    """

    signals = ('fr', 'psr')

    def __init__(self, **kwargs):
        super().__init__('scheduler', **kwargs)


def main_command_generator(args: Sequence[str] | None = None) -> int:
    return spin_standalone(CommandGenerator, args)


def main_scheduler(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Scheduler, args)
