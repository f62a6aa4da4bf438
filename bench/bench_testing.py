"""Throughput of playing bags and of deterministic replay, on the packaged reference bag
@paper_HD (1.0 s of the paper scenario, HD, 12 113 messages: 12 113 messages per second of
bag time).

- player: `servovalve-twin play`'s Player publishing every message as its recorded bytes, at
  rate 1 (paced by the bag) and at rate 1000 (as fast as it can publish), no subscriber;
- replay_into: the bag fed to nodes under test in one executor, deterministic: the example's
  LeakDetector in the algorithm node (4 input topics), and a node subscribing to all nine
  Float64 topics of the twin (each message deserialized and handed to a Python callback).

    ../shared/tools/isolated .venv/bin/python bench/bench_testing.py --repeat 5
"""

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'doc' / 'examples' / 'my_detector'))
BAG = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'


class AllFloats(Node):
    def __init__(self, ctx):
        super().__init__('all_floats', context=ctx,
                         parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.n = 0
        for t in ('com', 'fr', 'psr', 'cor', 'xs', 'xj', 'dxj', 'p12', 'qj'):
            self.create_subscription(Float64, t, self.cb, 10)

    def cb(self, msg):
        self.n += 1


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=5)
    args = ap.parse_args()
    from leak_detector import LeakDetector
    from servovalve_twin.bag.anybag import open_any_bag
    from servovalve_twin.nodes.algorithm import AlgorithmNode
    from servovalve_twin.nodes.player import PlayOptions, play
    from servovalve_twin.testing import replay_into
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    bag = open_any_bag(BAG)
    rows = []
    for rate in (1.0, 1000.0):
        walls = []
        for _ in range(args.repeat):
            r = play(BAG, PlayOptions(rate=rate), context=ctx, progress=False)
            walls.append(r['wall_s'])
        w = statistics.median(walls)
        rows.append((f'player, rate {rate:g}', bag.message_count, w))
    for label, make in (('replay_into, LeakDetector (algorithm node, 4 topics)',
                         lambda i: AlgorithmNode(LeakDetector(), name=f'det{i}', context=ctx,
                                                 parameter_overrides=[Parameter(
                                                     'use_sim_time', value=True)])),
                        ('replay_into, node on the 9 Float64 topics', lambda i: AllFloats(ctx))):
        walls = []
        n = 0
        for i in range(args.repeat):
            node = make(i)
            t0 = time.perf_counter()
            replay_into(node, BAG)
            walls.append(time.perf_counter() - t0)
            n = sum(1 for t in bag.topics if t in {s.topic_name for s in node.subscriptions}
                    for _ in range(bag.topics[t].count))
            node.destroy_node()
        rows.append((label, n, statistics.median(walls)))
    rclpy.try_shutdown(context=ctx)
    print(f'machine: {platform.processor() or platform.machine()}, Python '
          f'{platform.python_version()}; bag {BAG.name}: {bag.message_count} messages in '
          f'{bag.duration_ns * 1e-9:.3f} s of bag time; median of {args.repeat}')
    print('| what | messages | wall [s] | messages/s | bag time / wall time |')
    print('|---|---|---|---|---|')
    for label, n, w in rows:
        print(f'| {label} | {n} | {w:.3f} | {n / w:.0f} | {bag.duration_ns * 1e-9 / w:.1f} |')


if __name__ == '__main__':
    main()
