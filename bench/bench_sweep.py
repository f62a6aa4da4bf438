"""Fault-sweep throughput against the physics limit (HD plant + monitor, 1.0 s paper scenario,
ROS-free, 64 runs: half nominal, half leaking).

- the physics limit: one run's time in one process (plant simulation, monitor simulation,
  residuals, features: ``run_case``), median over the runs, and the limit ``workers / that``;
- a sweep through ``iter_results`` with 1 worker and one per core, rows only (what a dataset
  needs; traces on request), timed from the call to the last row -- the parent loads the
  compiled physics, then the pool forks: no worker compiles;
- the whole CLI, ``servovalve-twin sweep ...``, a fresh process: start-up, the sweep, writing
  the dataset and the signature plot.

    .venv/bin/python bench/bench_sweep.py [--runs 64]
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from servovalve_twin.prognostics.sweep import iter_results, make_cases, run_case


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--runs', type=int, default=64)
    args = ap.parse_args()
    sys.path.insert(0, 'bench')
    from bench_physics import machine
    cores = os.cpu_count() or 1
    print(f'machine: {machine()}; {args.runs} runs of the 1.0 s paper scenario, HD plant, '
          'half nominal, half leakage_growth 10, mass varied +-10 %')
    print('| monitor | one run [ms] | workers | sweep [s] | runs per second | physics limit '
          '[runs/s] | of the limit |')
    print('|---|---|---|---|---|---|---|')
    for monitor in ('C2', 'SQ'):
        cases = make_cases(monitor_model=monitor, nominal_runs=args.runs // 2,
                           faults={'leakage_growth': [10.0]}, repeats=args.runs // 2,
                           vary={'M': 0.1})
        run_case(cases[0], False)
        one = []
        for c in cases[:16]:
            t = time.perf_counter()
            run_case(c, False)
            one.append(time.perf_counter() - t)
        one = statistics.median(one)
        for workers in (1, cores):
            t = time.perf_counter()
            for _ in iter_results(cases, workers=workers, traces=False):
                pass
            wall = time.perf_counter() - t
            limit = workers / one
            print(f'| {monitor} | {one * 1e3:.1f} | {workers} | {wall:.2f} | '
                  f'{len(cases) / wall:.0f} | {limit:.0f} | {len(cases) / wall / limit:.0%} |')
    out = tempfile.mkdtemp()
    exe = os.path.join(os.path.dirname(sys.executable), 'servovalve-twin')
    cmd = [exe, 'sweep', '--fault', 'leakage_growth:10', '--repeats', str(args.runs // 2),
           '--nominal', str(args.runs // 2), '--vary', 'M=0.1']
    walls = []
    for i in range(3):
        t = time.perf_counter()
        subprocess.run(cmd + ['--out', os.path.join(out, f's{i}')], check=True,
                       capture_output=True)
        walls.append(time.perf_counter() - t)
    print(f'\nThe whole CLI (`servovalve-twin sweep --fault leakage_growth:10 --repeats '
          f'{args.runs // 2} --nominal {args.runs // 2} --vary M=0.1`, {cores} workers, fresh '
          f'process, median of 3): {statistics.median(walls):.2f} s')


if __name__ == '__main__':
    main()
