"""Fault-sweep throughput: runs per second of `sweep` on this machine (HD plant + monitor,
1.0 s paper scenario, ROS-free), with 1 worker and with the default (one per core). Each run
is a plant simulation, a monitor simulation, residuals and features; per-process numba
compilation is included (it is part of what a user waits for).

    .venv/bin/python bench/bench_sweep.py [--runs 64]
"""

import argparse
import os
import sys
import time

from servovalve_twin.prognostics.sweep import make_cases, run_cases


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--runs', type=int, default=64)
    args = ap.parse_args()
    sys.path.insert(0, 'bench')
    from bench_physics import machine
    print(f'machine: {machine()}; {args.runs} runs of the 1.0 s paper scenario, HD plant')
    print('| monitor | workers | wall [s] | runs per second |')
    print('|---|---|---|---|')
    for monitor in ('C2', 'SQ'):
        cases = make_cases(monitor_model=monitor, nominal_runs=args.runs // 2,
                           faults={'leakage_growth': [10.0]}, repeats=args.runs // 2,
                           vary={'M': 0.1})
        for workers in (1, os.cpu_count() or 1):
            t = time.perf_counter()
            run_cases(cases, workers=workers)
            wall = time.perf_counter() - t
            print(f'| {monitor} | {workers} | {wall:.2f} | {len(cases) / wall:.1f} |')


if __name__ == '__main__':
    main()
