"""How a flight calibration's units scale: units per second on local processes and on a Dask
cluster of N worker processes (N = 1, 2), and Dask's overhead per unit.

The work is ``calibrate_flight`` of a flight of its own (``--duration`` s of steps under load,
every catalog fault a simplified model can see, ``--units`` per fault and level), each
configuration with an empty cache of its own (nothing is read back). The overhead per unit is
the cluster's wall time per unit at N = 1 less the local single process's.

    .venv/bin/python bench/bench_parallel.py [--duration 0.5] [--units 1] [--json F]

(Run through ../shared/tools/isolated: Dask listens on loopback.)
"""

import argparse
import json
import os
import sys
import tempfile
import time

import distributed

from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics import flight_calibration as fc


def flight(duration: float) -> dict:
    return {'duration': duration,
            'com': [[0.0, 0.0], [0.05, 0.02], [0.25 * duration, 0.02], [0.3 * duration, -0.015]],
            'fr': [[0.0, 0.0], [0.1, 2500.0], [0.6 * duration, -2000.0]],
            'psr': [[0.0, 2.0e7]]}


def timed(label: str, faults: list, **kw) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        os.environ[fc.CACHE_ENV] = cache
        t = time.perf_counter()
        fc.calibrate_flight(FLIGHT, DEFAULTS, units=UNITS, faults=faults, **kw)
        wall = time.perf_counter() - t
    n = len(fc.jobs(faults, UNITS, 0))
    row = dict(config=label, units=n, wall_s=round(wall, 2), units_per_s=round(n / wall, 3))
    print(f'{label:24s} {n} units in {wall:7.2f} s: {n / wall:6.3f} units/s', flush=True)
    return row


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--duration', type=float, default=0.5)
    ap.add_argument('--units', type=int, default=1)
    ap.add_argument('--json')
    a = ap.parse_args()
    from servovalve_twin.prognostics.rules import DIAGNOSABLE
    FAULTS, UNITS, FLIGHT = list(DIAGNOSABLE), a.units, flight(a.duration)
    print(f'{os.cpu_count()} cores; flight {a.duration:g} s, {a.units} unit(s) per fault '
          'and level', flush=True)
    timed('warm-up (compiles)', workers=1, faults=FAULTS[:1])
    rows = [timed('local, 1 process', workers=1, faults=FAULTS),
            timed('local, 2 processes', workers=2, faults=FAULTS)]
    for n in (1, 2):
        with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster:
            rows.append(timed(f'Dask, {n} worker(s)', faults=FAULTS,
                              scheduler=cluster.scheduler_address))
    d1, d2 = rows[2]['units_per_s'], rows[3]['units_per_s']
    overhead = rows[2]['wall_s'] / rows[2]['units'] - rows[0]['wall_s'] / rows[0]['units']
    print(f'Dask 2 workers / 1 worker: {d2 / d1:.2f} x (0.8 N = 1.6); overhead per unit '
          f'{overhead * 1e3:.0f} ms', flush=True)
    if a.json:
        with open(a.json, 'w') as fh:
            json.dump(dict(rows=rows, scaling=d2 / d1, overhead_s=overhead), fh, indent=1)
    sys.exit(0)
