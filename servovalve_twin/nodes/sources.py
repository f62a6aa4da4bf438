"""Schedule nodes: the command generator (Com) and the load and supply node (FR, PSR).

Both read a scenario (:mod:`servovalve_twin.physics.scenario`) and publish its values at the
scenario time. Alone, a timer with period ``control_period`` drives them on the node clock (wall
time, or ``/clock`` when ``use_sim_time`` is true), scenario time counting from the first tick
with a valid time (with ``use_sim_time``, nothing is published before the first ``/clock``);
after the scenario's end the last values are held. Inside ``twin`` the orchestrator evaluates
the whole schedule once and calls :meth:`ScheduleSource.publish_values` once per tick instead
(no timer), which is what makes the lockstep deterministic; there the ``scenario`` parameter
names the scenario the twin runs and is read-only.
"""

from __future__ import annotations

from typing import Any, Sequence

from rcl_interfaces.msg import ParameterDescriptor

from ..config import load_scenario
from ..physics.scenario import Scenario
from .base import TwinNode
from .process import spin_standalone


class ScheduleSource(TwinNode):
    """Base of the schedule nodes: the scenario they own, timer or lockstep, publishers."""

    signals: tuple[str, ...] = ()
    period_doc = 'publication period [s] when running alone'

    def __init__(self, name: str, *, scenario: Scenario | None = None, **kwargs):
        """``scenario``: the loaded scenario (the twin's, loaded once; its ``scenario``
        parameter then names it); None loads the ``scenario`` parameter."""
        super().__init__(name, **kwargs)
        self.declare_parameter('scenario', 'paper', ParameterDescriptor(
            description="built-in scenario name ('paper', 'defaults', ...) or a YAML file",
            read_only=self.lockstep))
        if scenario is None:
            scenario = load_scenario(self.get_parameter('scenario').value)
        self.scenario: Scenario = scenario
        self.add_publishers(self.signals)
        self._t0_ns: int | None = None
        self.start()

    def check_parameters(self, changes: dict[str, Any]) -> None:
        # in the lockstep the parameter only names the twin's scenario (read-only)
        if 'scenario' in changes and not self.lockstep:
            load_scenario(changes['scenario'])

    def apply_parameters(self, changes: dict[str, Any]) -> None:
        if 'scenario' in changes and not self.lockstep:
            self.scenario = load_scenario(changes['scenario'])
            self._t0_ns = None
            self.get_logger().info(f'scenario {self.scenario.name!r} loaded')

    def values(self, t_ns: int) -> dict[str, float]:
        """The scenario's signals at scenario time ``t_ns``."""
        t = min(t_ns, self.scenario.duration_ns)
        return {s: getattr(self.scenario, s).value(t) for s in self.signals}

    def publish_values(self, values: dict[str, float]) -> None:
        """Publish given values (the lockstep evaluates the whole schedule up front)."""
        for s, v in values.items():
            self.emit_value(s, v)

    def on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        if now == 0:
            return          # use_sim_time and no /clock received yet: time is not valid
        if self._t0_ns is None or now < self._t0_ns:     # first tick, or sim time reset
            self._t0_ns = now
        self.publish_values(self.values(now - self._t0_ns))


class CommandGenerator(ScheduleSource):
    """Publishes the position command.

    Publishes: ``com`` (std_msgs/Float64, m).
    Parameters: ``scenario`` (string), ``control_period`` (double, s, read-only).
    """

    signals = ('com',)

    def __init__(self, **kwargs):
        super().__init__('command_generator', **kwargs)


class LoadSupply(ScheduleSource):
    """Publishes what the actuator's surroundings impose: the external load and the supply.

    Publishes: ``fr`` (std_msgs/Float64, N, > 0 opposes +XJ), ``psr`` (std_msgs/Float64, Pa).
    Parameters: ``scenario`` (string), ``control_period`` (double, s, read-only).
    """

    signals = ('fr', 'psr')

    def __init__(self, **kwargs):
        super().__init__('load_supply', **kwargs)


def main_command_generator(args: Sequence[str] | None = None) -> int:
    return spin_standalone(CommandGenerator, args)


def main_load_supply(args: Sequence[str] | None = None) -> int:
    return spin_standalone(LoadSupply, args)
