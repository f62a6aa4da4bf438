"""Physics speed: the 1.0 s paper scenario at DT = 1e-5 s (100 000 plant steps), ROS-free,
one core, and what a user waits for around it.

1. Per model, in a fresh process: the first call (the loop compiled ahead of time, or numba
   loading it from its disk cache where that module is not built), the whole
   ``simulate(model, 'paper')`` call (median of --repeat), the compiled loop alone on prebuilt
   inputs, us per plant step and the real-time factor of the whole call.
2. Start-up of one CLI process, interleaved rounds, medians: ``python -c "import numpy,
   numba"`` (the floor of any numba program), the same plus one call of a trivial cached
   numba function (numba's own first-call set-up), ``servovalve-twin simulate --valve-model C2``
   with the loops compiled ahead of time (:mod:`servovalve_twin.aot`; an empty numba cache),
   with the JIT's warm cache, and the JIT's first-ever call (an empty numba cache: everything
   compiles).
3. SQ's step cost over C2's, and C2 read by three noisy sensors over C2 with ideal ones,
   interleaved in one process (small ratios need one run).
4. Units per second of a fleet (``simulate_many``, 3 and 8 units) over the same units run one
   by one, per model, each in a process of its own.

    .venv/bin/python bench/bench_physics.py [--repeat 9] [--rounds 7]
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

CHILD = '''
import sys, time, json
import numpy as np
t = time.perf_counter()
from servovalve_twin.runs import simulate
from servovalve_twin.config import load_scenario
from servovalve_twin.physics import simulate as S
from servovalve_twin.physics.plant import run_steps_for
from servovalve_twin.physics.sensors import sensor_table
from servovalve_twin.physics.servovalve import S_SIZE
from servovalve_twin.physics.valves import get_valve_model
imp = time.perf_counter() - t
model, repeat = sys.argv[1], int(sys.argv[2])
t = time.perf_counter(); r = simulate(model, 'paper'); first = time.perf_counter() - t
walls = []
for _ in range(repeat):
    walls.append(simulate(model, 'paper').info['wall_s'])
# the compiled loop alone: inputs, state and output built beforehand
scn = load_scenario('paper'); p = S.effective_params(scn); m = get_valve_model(model)
n = scn.duration_ns // p.dt_ns
com, fr, psr = scn.inputs(np.arange(n + 1, dtype=np.int64) * p.dt_ns)
kern, start = S._fault_segments(m, scn, p)
loops = []
for _ in range(repeat):
    out = np.full((n // 100 + 1, 12), np.nan); s = np.zeros(S_SIZE); vs = m.initial_state(p)
    t = time.perf_counter()
    run_steps_for(m.id, False)(s, vs, kern, start, com, fr, psr, 0, n, 0, 100, np.zeros(2), out,
                               1e-3, *sensor_table(None, 100, p.DT), np.zeros(6), 100)
    loops.append(time.perf_counter() - t)
print(json.dumps(dict(first=first, walls=walls, loops=loops, steps=r.info['steps'], imp=imp)))
'''

TRIVIAL = '''
from numba import njit
@njit(cache=True)
def f(x):
    return x + 1.0
f(1.0)
'''

RATIO = '''
import sys, time, json
from servovalve_twin.runs import simulate
from servovalve_twin.config import load_scenario
from servovalve_twin.prognostics.calibration_set import NOISE
# the paper scenario read by noisy XJ, DXJ and P12 sensors (the documented noise levels)
noisy = dict(load_scenario('paper').to_dict(),
             sensors={'seed': 1, **{k: {'noise': v} for k, v in NOISE.items()}})
simulate('C2'); simulate('SQ'); simulate('C2', noisy)
ratios, sensed = [], []
for _ in range(int(sys.argv[1])):
    c2 = min(simulate('C2').info['wall_s'] for _ in range(3))
    sq = min(simulate('SQ').info['wall_s'] for _ in range(3))
    c2s = min(simulate('C2', noisy).info['wall_s'] for _ in range(3))
    ratios.append(sq / c2)
    sensed.append(c2s / c2)
print(json.dumps(dict(sq=ratios, sensed=sensed)))
'''

#: a fleet of N units (masses apart) in one call against the same units one by one, per
#: model, in a process of its own (interleaved with other runs, the ratios moved by 30 %)
FLEET = '''
import sys, time, json
from servovalve_twin.config import load_scenario
from servovalve_twin.physics.fleet import simulate_many
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.physics.simulate import simulate
model, n, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
paper = load_scenario('paper')
units = [DEFAULTS.replace(M=480.0 + 5 * k) for k in range(n)]

def fleet():
    t = time.perf_counter()
    simulate_many(model, paper, units, ecu_period=1e-3)
    return time.perf_counter() - t

def one_by_one():
    t = time.perf_counter()
    for p in units:
        simulate(model, paper, params=p, ecu_period=1e-3)
    return time.perf_counter() - t
fleet(); one_by_one()
print(json.dumps([min(one_by_one() for _ in range(3)) / min(fleet() for _ in range(3))
                  for _ in range(repeat)]))
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
    return f'{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}'


def _wall(cmd, env=None) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    return time.perf_counter() - t


def startup(rounds: int) -> None:
    exe = os.path.join(os.path.dirname(sys.executable), 'servovalve-twin')
    tmp = tempfile.mkdtemp()
    trivial = os.path.join(tmp, 'trivial.py')
    with open(trivial, 'w') as fh:
        fh.write(TRIVIAL)
    cases = {
        'python -c "import numpy, numba"': lambda i: _wall([sys.executable, '-c',
                                                            'import numpy, numba']),
        'a trivial cached numba function, first call': lambda i: _wall([sys.executable,
                                                                         trivial]),
        'servovalve-twin simulate --valve-model C2 (loops compiled ahead of time)':
            lambda i: _wall([exe, 'simulate', '--valve-model', 'C2', '--out',
                             os.path.join(tmp, f'a{i}.csv')],
                            env=dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, f'aot{i}'))),
        'the same with the JIT (warm numba cache)': lambda i: _wall(
            [exe, 'simulate', '--valve-model', 'C2', '--out', os.path.join(tmp, f'w{i}.csv')],
            env=dict(os.environ, SERVOVALVE_TWIN_JIT='1')),
        'the same with the JIT, first ever (empty numba cache: compiles)': lambda i: _wall(
            [exe, 'simulate', '--valve-model', 'C2', '--out', os.path.join(tmp, f'f{i}.csv')],
            env=dict(os.environ, SERVOVALVE_TWIN_JIT='1',
                     NUMBA_CACHE_DIR=os.path.join(tmp, f'cache{i}'))),
    }
    _wall([exe, 'simulate', '--valve-model', 'C2', '--out', os.path.join(tmp, 'x.csv')],
          env=dict(os.environ, SERVOVALVE_TWIN_JIT='1'))
    times = {k: [] for k in cases}
    for i in range(rounds):                       # interleaved: drift hits every line alike
        for k, fn in cases.items():
            times[k].append(fn(i))
    floor = statistics.median(times['python -c "import numpy, numba"'])
    print(f'\nStart-up of one process, median of {rounds} interleaved rounds:\n')
    print('| process | wall [s] | / import floor |')
    print('|---|---|---|')
    for k, v in times.items():
        med = statistics.median(v)
        print(f'| {k} | {med:.2f} | {med / floor:.2f} |')


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--repeat', type=int, default=9)
    ap.add_argument('--rounds', type=int, default=7)
    args = ap.parse_args()
    from servovalve_twin.physics.valves import VALVE_MODEL_NAMES
    print(f'machine: {machine()}; 1.0 s paper scenario, DT = 1e-5 s, median of {args.repeat} '
          'runs per model in a fresh process')
    print('| model | first call [s] | simulate() [ms] | compiled loop [ms] | whole / loop | '
          'us per plant step | real-time factor |')
    print('|---|---|---|---|---|---|---|')
    for model in VALVE_MODEL_NAMES:
        out = subprocess.run([sys.executable, '-c', CHILD, model, str(args.repeat)],
                             capture_output=True, text=True, check=True).stdout
        d = json.loads(out.strip().splitlines()[-1])
        med = statistics.median(d['walls'])
        loop = statistics.median(d['loops'])
        print(f'| {model} | {d["first"]:.2f} | {med * 1e3:.2f} | {loop * 1e3:.2f} | '
              f'{med / loop:.2f} | {med / d["steps"] * 1e6:.3f} | {1.0 / med:.0f} |')
    startup(args.rounds)
    out = subprocess.run([sys.executable, '-c', RATIO, str(args.repeat)], capture_output=True,
                         text=True, check=True).stdout
    got = json.loads(out.strip().splitlines()[-1])
    for what, ratios in (('SQ / C2 whole-call cost', got['sq']),
                         ('C2 read by three noisy sensors / C2 ideal', got['sensed'])):
        print(f'\n{what}, interleaved in one process: median '
              f'{statistics.median(ratios):.2f} (min {min(ratios):.2f}, max '
              f'{max(ratios):.2f}, {len(ratios)} pairs)')
    print('\nUnits per second, simulate_many of N units / the same units one by one '
          '(1 ms ECU; a process per model, median of the pairs):\n')
    print('| model | N = 3 | N = 8 |')
    print('|---|---|---|')
    for model in ('C2', 'SQ', 'HD'):
        cells = []
        for n in (3, 8):
            out = subprocess.run([sys.executable, '-c', FLEET, model, str(n), str(args.repeat)],
                                 capture_output=True, text=True, check=True).stdout
            cells.append(f'{statistics.median(json.loads(out.strip().splitlines()[-1])):.2f}')
        print(f'| {model} | {cells[0]} | {cells[1]} |')


if __name__ == '__main__':
    main()
