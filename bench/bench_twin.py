"""Speed of the ROS twin: real-time factor (simulated s / wall s) of the 1.0 s paper scenario at
a 1 ms control period, in one process, with and without the bag; the ROS overhead, twin wall
time / simulate (same sampled ECU) wall time; where a tick's time goes; and rclpy's own floor
on this machine.

1. configurations, each in a fresh process: one warm-up run, then --repeat runs, medians;
2. a tick broken down by ablation (C2, interleaved rounds in one process): the whole tick with
   the bag; without it (the recorder's share); without the executor's turns (the graph
   period made longer than the run); the plant's physics call alone (``EhaPlant.tick``); the
   rest is the nodes' Python (inputs, lockstep, outputs);
3. rclpy's floor: a Float64 publish with no subscriber (message, and serialized bytes), and
   publish plus delivery to a subscriber in the same process on an EventsExecutor.

Run it inside ../shared/tools/isolated:

    ../shared/tools/isolated .venv/bin/python bench/bench_twin.py [--repeat 7]
"""

import argparse
import json
import statistics
import subprocess
import sys

CHILD = '''
import json, sys, tempfile, os
from servovalve_twin.twin import TwinConfig, run_twin
from servovalve_twin.runs import simulate
model, bag, executor, repeat = sys.argv[1], sys.argv[2] == '1', sys.argv[3], int(sys.argv[4])
monitor = sys.argv[5] if sys.argv[5] != '-' else None
tmp = tempfile.mkdtemp()
def one(i):
    r = run_twin(TwinConfig(model, 'paper', bag=os.path.join(tmp, f'b{i}'), record=bag,
                            monitor=monitor or ''), executor=executor, keep_values=False)
    return r.wall_s
one('warm')
walls = [one(i) for i in range(repeat)]
simulate(model, 'paper', ecu_period=1e-3)
sims = [simulate(model, 'paper', ecu_period=1e-3).info['wall_s'] for _ in range(repeat)]
print(json.dumps(dict(walls=walls, sims=sims)))
'''

BREAKDOWN = '''
import json, sys, tempfile, os, time
from servovalve_twin.twin import TwinConfig, lockstep, run_twin
from servovalve_twin.physics.simulate import EhaPlant
from servovalve_twin.config import load_scenario
import numpy as np
rounds = int(sys.argv[1])
tmp = tempfile.mkdtemp()
scn = load_scenario('paper')
com, fr, psr = scn.inputs(np.arange(1001, dtype=np.int64) * 1_000_000)
def physics():
    plant = EhaPlant('C2'); plant.compile()
    t = time.perf_counter()
    for k in range(1001):
        cor = plant.control(com[k], plant.xj)
        plant.tick(cor, fr[k], psr[k], 100 if k < 1000 else 0)
    return time.perf_counter() - t
def twin(bag, turns, i):
    saved = lockstep.GRAPH_PERIOD_NS
    if not turns:
        lockstep.GRAPH_PERIOD_NS = 10**12          # one turn, at t = 0
    try:
        return run_twin(TwinConfig('C2', 'paper', bag=os.path.join(tmp, f'b{i}'), record=bag),
                        keep_values=False).wall_s
    finally:
        lockstep.GRAPH_PERIOD_NS = saved
twin(True, True, 'warm')
out = {k: [] for k in ('full', 'nobag', 'noturns', 'physics')}
for i in range(rounds):
    out['full'].append(twin(True, True, i))
    out['nobag'].append(twin(False, True, i))
    out['noturns'].append(twin(False, False, i))
    out['physics'].append(physics())
print(json.dumps(out))
'''

FLOOR = '''
import json, sys, time
import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
from servovalve_twin.nodes.topics import QOS
n = int(sys.argv[1])
ctx = Context(); rclpy.init(context=ctx)
node = Node('floor', context=ctx)
ex = EventsExecutor(context=ctx); ex.add_node(node)
msg = Float64(data=1.0)
lonely = node.create_publisher(Float64, 'nobody', QOS)
t = time.perf_counter()
for _ in range(n):
    lonely.publish(msg)
no_sub = (time.perf_counter() - t) / n
raw = serialize_message(msg)
t = time.perf_counter()
for _ in range(n):
    lonely.publish(raw)
no_sub_bytes = (time.perf_counter() - t) / n
got = []
node.create_subscription(Float64, 'echo', lambda m: got.append(m.data), QOS)
pub = node.create_publisher(Float64, 'echo', QOS)
deadline = time.monotonic() + 10
while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
    time.sleep(0.01)
for _ in range(100):                               # warm the path
    pub.publish(msg); ex.spin_once(timeout_sec=1.0)
got.clear()
t = time.perf_counter()
for i in range(n):
    pub.publish(msg)
    while len(got) <= i:
        ex.spin_once(timeout_sec=1.0)
delivered = (time.perf_counter() - t) / n
print(json.dumps(dict(no_sub=no_sub, no_sub_bytes=no_sub_bytes, delivered=delivered)))
'''

CONFIGS = [  # model, bag, executor, monitor; the first of each model is the default
    ('C2', True, 'events', None), ('C2', False, 'events', None),
    ('HD', True, 'events', None), ('HD', False, 'events', None),
    ('SQ', True, 'events', None), ('HD', True, 'events', 'C2'),
    ('C2', True, 'single', None),
]

#: Float64 values a tick hands between the twin's nodes (xs, xj, dxj, com, fr, psr, cor to
#: the plant and ECU): each was a DDS round trip before they went in process
LOCKSTEP_INPUTS = 7


def _child(code, *args):
    out = subprocess.run([sys.executable, '-c', code, *map(str, args)], capture_output=True,
                         text=True)
    if out.returncode:
        print(out.stderr[-2000:], file=sys.stderr)
        raise SystemExit(1)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=7)
    args = ap.parse_args()
    sys.path.insert(0, 'bench')
    from bench_physics import machine
    print(f'machine: {machine()}; 1.0 s paper scenario, 1 ms control period (1001 ticks), '
          f'/clock every 10 ms; median of {args.repeat} runs after a warm-up, each '
          'configuration in a fresh process')
    print('| valve model | monitor | executor | bag | wall [s] | real-time factor | '
          'ROS overhead (twin / simulate) | us per tick |')
    print('|---|---|---|---|---|---|---|---|')
    for model, bag, executor, monitor in CONFIGS:
        d = _child(CHILD, model, '1' if bag else '0', executor, args.repeat, monitor or '-')
        w, s = statistics.median(d['walls']), statistics.median(d['sims'])
        print(f'| {model} | {monitor or "-"} | {executor} | {"on" if bag else "off"} | '
              f'{w:.3f} | {1.0 / w:.1f} | {w / s:.0f}x | {w / 1001 * 1e6:.0f} |')

    d = {k: statistics.median(v) * 1e6 / 1001 for k, v in
         _child(BREAKDOWN, args.repeat).items()}
    print(f'\nA C2 tick, by ablation (median of {args.repeat} interleaved rounds, us per tick):\n')
    print('| part | us per tick | share |')
    print('|---|---|---|')
    parts = [('recorder (bag on - bag off)', d['full'] - d['nobag']),
             ('executor turns every 100 ms (bag off - no turns)', d['nobag'] - d['noturns']),
             ('plant physics call (EhaPlant.tick, ECU law included)', d['physics']),
             ('nodes\' Python: inputs, lockstep, outputs (the rest)',
              d['noturns'] - d['physics'])]
    for name, us in parts:
        print(f'| {name} | {us:.1f} | {us / d["full"]:.0%} |')
    print(f'| whole tick, bag on | {d["full"]:.1f} | 100% |')

    f = {k: v * 1e6 for k, v in _child(FLOOR, 5000).items()}
    print('\nrclpy on this machine (Fast DDS, one process, 5000 messages):\n')
    print('| what | us per message |')
    print('|---|---|')
    print(f'| Float64 publish, no subscriber | {f["no_sub"]:.2f} |')
    print(f'| the same as serialized bytes | {f["no_sub_bytes"]:.2f} |')
    print(f'| publish + delivery to a subscriber (EventsExecutor) | {f["delivered"]:.1f} |')
    print(f'| {LOCKSTEP_INPUTS} lockstep inputs through DDS, per tick (the floor of the old '
          f'design: RTF <= {1e3 / (LOCKSTEP_INPUTS * f["delivered"]):.0f}) | '
          f'{LOCKSTEP_INPUTS * f["delivered"]:.0f} |')


if __name__ == '__main__':
    main()
