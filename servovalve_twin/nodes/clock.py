"""The ``clock`` executable: publishes ``/clock`` so that several processes share simulated
time (``use_sim_time:=true`` on each).

Parameters: ``rate`` (double, simulated seconds per wall second, default 1.0), ``period``
(double, s of simulated time between messages, default 0.001), ``start`` (double, s).
"""

from __future__ import annotations

from typing import Sequence

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.clock import Clock as RclClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from .process import spin_standalone


def clock_msg(t_ns: int) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
    return msg


class ClockPublisher(Node):
    """Publishes: ``/clock`` (rosgraph_msgs/Clock)."""

    def __init__(self, **kwargs):
        super().__init__('clock', **kwargs)
        positive = [FloatingPointRange(from_value=1e-6, to_value=1e6, step=0.0)]
        self.declare_parameter('rate', 1.0, ParameterDescriptor(
            description='simulated seconds per wall second', floating_point_range=positive,
            read_only=True))
        self.declare_parameter('period', 0.001, ParameterDescriptor(
            description='simulated time between /clock messages [s]',
            floating_point_range=positive, read_only=True))
        self.declare_parameter('start', 0.0, ParameterDescriptor(
            description='initial simulated time [s]', read_only=True))
        self.pub = self.create_publisher(Clock, '/clock', 10)
        self.period_ns = int(round(self.get_parameter('period').value * 1e9))
        self.t_ns = int(round(self.get_parameter('start').value * 1e9))
        # paced by the steady wall clock: this node is the source of simulated time
        self.create_timer(self.period_ns * 1e-9 / self.get_parameter('rate').value,
                          self._on_timer, clock=RclClock(clock_type=ClockType.STEADY_TIME))

    def _on_timer(self) -> None:
        self.pub.publish(clock_msg(self.t_ns))
        self.t_ns += self.period_ns


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(ClockPublisher, args)
