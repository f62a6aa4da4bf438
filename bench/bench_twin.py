"""Speed of the ROS twin: real-time factor (simulated s / wall s) of the 1.0 s paper scenario
at a 1 ms control period, in one process on one EventsExecutor, with and without the bag, with
/clock every tick or every 10 ticks, and with the SingleThreadedExecutor for comparison; and the
ROS overhead, twin wall time / simulate (same sampled ECU) wall time.

Each configuration runs in a fresh process: one warm-up run (JIT compile), then --repeat runs;
medians. Run it inside ../shared/tools/isolated:

    ../shared/tools/isolated .venv/bin/python bench/bench_twin.py [--repeat 5]
"""

import argparse
import json
import statistics
import subprocess
import sys

CHILD = '''
import json, sys, time, tempfile, os
from servovalve_twin.twin import run_twin
from servovalve_twin.runs import simulate
model, bag, executor = sys.argv[1], sys.argv[2] == '1', sys.argv[4]
clock, repeat = float(sys.argv[3]), int(sys.argv[5])
tmp = tempfile.mkdtemp()
def one(i):
    r = run_twin(model, 'paper', bag=os.path.join(tmp, f'b{i}') if bag else None,
                 clock_period=clock, executor=executor, keep_values=False)
    return r.wall_s
one('warm')
walls = [one(i) for i in range(repeat)]
simulate(model, 'paper', ecu_period=1e-3)
sims = [simulate(model, 'paper', ecu_period=1e-3).info['wall_s'] for _ in range(repeat)]
print(json.dumps(dict(walls=walls, sims=sims)))
'''

CONFIGS = [  # model, bag, /clock period, executor; the first of each model is the default
    ('C2', True, 1e-2, 'events'), ('C2', False, 1e-2, 'events'), ('C2', True, 1e-3, 'events'),
    ('HD', True, 1e-2, 'events'), ('HD', False, 1e-2, 'events'),
    ('SQ', True, 1e-2, 'events'),
    ('C2', True, 1e-2, 'single'),
]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=5)
    args = ap.parse_args()
    sys.path.insert(0, 'bench')
    from bench_physics import machine
    print(f'machine: {machine()}; 1.0 s paper scenario, 1 ms control period, median of '
          f'{args.repeat} runs after a warm-up, each configuration in a fresh process')
    print('| valve model | executor | bag | /clock every | wall [s] | real-time factor | '
          'ROS overhead (twin / simulate) | us per tick |')
    print('|---|---|---|---|---|---|---|---|')
    for model, bag, clock, executor in CONFIGS:
        out = subprocess.run([sys.executable, '-c', CHILD, model, '1' if bag else '0',
                              str(clock), executor, str(args.repeat)], capture_output=True,
                             text=True)
        if out.returncode:
            print(out.stderr[-2000:], file=sys.stderr)
            raise SystemExit(1)
        d = json.loads(out.stdout.strip().splitlines()[-1])
        w, s = statistics.median(d['walls']), statistics.median(d['sims'])
        print(f'| {model} | {executor} | {"on" if bag else "off"} | {clock * 1e3:g} ms | '
              f'{w:.3f} | {1.0 / w:.1f} | {w / s:.0f}x | {w / 1001 * 1e6:.0f} |')


if __name__ == '__main__':
    main()
