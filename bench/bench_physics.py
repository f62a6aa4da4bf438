"""Physics speed: the 1.0 s paper scenario at DT = 1e-5 s (100 000 plant steps), ROS-free,
one core. Per model: one-off compile cost (first call in a fresh process, numba JIT), then the
median wall time of --repeat runs, us per plant step and the real-time factor.

    .venv/bin/python bench/bench_physics.py [--repeat 7] [--markdown]
"""

import argparse
import platform
import statistics
import subprocess
import sys

CHILD = '''
import sys, time, json
t = time.perf_counter()
from servovalve_twin.runs import simulate
imp = time.perf_counter() - t
model, repeat = sys.argv[1], int(sys.argv[2])
t = time.perf_counter(); r = simulate(model, 'paper'); first = time.perf_counter() - t
walls = []
for _ in range(repeat):
    r = simulate(model, 'paper')
    walls.append(r.info['wall_s'])
print(json.dumps(dict(first=first, walls=walls, steps=r.info['steps'], imp=imp)))
'''


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo') as fh:
            for line in fh:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    import os
    return f'{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}'


def main() -> None:
    import json
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=7)
    ap.add_argument('--markdown', action='store_true')
    args = ap.parse_args()
    from servovalve_twin.physics.valves import VALVE_MODEL_NAMES
    rows = []
    for model in VALVE_MODEL_NAMES:
        out = subprocess.run([sys.executable, '-c', CHILD, model, str(args.repeat)],
                             capture_output=True, text=True, check=True).stdout
        d = json.loads(out.strip().splitlines()[-1])
        med = statistics.median(d['walls'])
        rows.append((model, d['first'] - med, med, med / d['steps'] * 1e6, 1.0 / med))
    print(f'machine: {machine()}; median of {args.repeat} runs, 1.0 s paper scenario, '
          'DT = 1e-5 s')
    print('| model | compile, one-off [s] | run [ms] | us per plant step | real-time factor |')
    print('|---|---|---|---|---|')
    for model, comp, med, us, rtf in rows:
        print(f'| {model} | {comp:.2f} | {med * 1e3:.2f} | {us:.3f} | {rtf:.0f} |')


if __name__ == '__main__':
    main()
