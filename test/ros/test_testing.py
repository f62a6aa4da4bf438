"""servovalve_twin.testing.replay_into: a node's sim-time timers fire at exactly the recorded
instants, whether or not the node was built with use_sim_time."""

from pathlib import Path

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

import servovalve_twin
from servovalve_twin.testing import replay_into

PAPER_HD = Path(servovalve_twin.__file__).parent / 'data' / 'paper_HD'


class _Ticker(Node):
    """Subscribes to /xj (so the replay drives it) and publishes /tick from a 100 Hz timer."""

    def __init__(self, context, sim_time: bool):
        super().__init__('ticker', context=context, parameter_overrides=(
            [Parameter('use_sim_time', value=True)] if sim_time else []))
        self.create_subscription(Float64, '/xj', lambda m: None, 10)
        pub = self.create_publisher(Float64, '/tick', 10)
        self.create_timer(0.01, lambda: pub.publish(Float64(data=1.0)))


@pytest.mark.parametrize('sim_time', [False, True])
def test_a_100_hz_timer_fires_100_times_over_a_1_s_bag(ros_context, sim_time):
    """The packaged 1 s bag (a message every 1 ms from 0): 100 firings stamped 10, 20, ...,
    1000 ms. A node built without use_sim_time, switched by the replay, got 99 stamped 11,
    21, ..., 991 ms (its wall-time credit restored at the replay's first 1 ms step)."""
    node = _Ticker(ros_context, sim_time)
    try:
        out = replay_into(node, PAPER_HD)
    finally:
        node.destroy_node()
    stamps = [t for t, _ in out['/tick']]
    assert stamps == [10_000_000 * k for k in range(1, 101)]
