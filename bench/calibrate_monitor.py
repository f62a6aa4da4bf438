"""Rebuild the packaged monitor thresholds (``servovalve_twin/data/monitor_calibration.json``;
what they are and why: :mod:`servovalve_twin.prognostics.monitor`): healthy HD units on the
calibration flights, every monitor model's peak indicators, Gumbel quantiles at the stated
per-flight false-alarm rates. About a minute.

    .venv/bin/python bench/calibrate_monitor.py [--units 4] [--seed 11] [--out FILE]
"""

import argparse
import json
import sys
import time

from servovalve_twin.physics.valves import MONITOR_MODEL_NAMES
from servovalve_twin.prognostics.monitor import MONITOR_CALIBRATION_FILE
from servovalve_twin.prognostics.thresholds import (FALSE_ALARM_RATE, calibrate_thresholds,
                                                    healthy_peaks, monitor_cal_flights)

SPREAD = 1.5


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--units', type=int, default=4, help='healthy units per flight')
    ap.add_argument('--seed', type=int, default=11)
    ap.add_argument('--out', default=str(MONITOR_CALIBRATION_FILE))
    args = ap.parse_args()
    flights = monitor_cal_flights()
    t0 = time.perf_counter()
    peaks = healthy_peaks(MONITOR_MODEL_NAMES, flights, args.units, args.seed, spread=SPREAD)
    out = dict(about=dict(plant='HD', flights=sorted(flights), units=args.units,
                          seed=args.seed, spread=SPREAD, noise='documented (calibration_set.NOISE)',
                          false_alarm_rate=FALSE_ALARM_RATE, law='Gumbel by moments',
                          runs=len(flights) * args.units),
               thresholds={m: calibrate_thresholds(peaks[m]) for m in MONITOR_MODEL_NAMES})
    with open(args.out, 'w', encoding='utf-8') as fh:
        json.dump(out, fh, indent=1, sort_keys=True)
        fh.write('\n')
    print(f'{out["about"]["runs"]} healthy HD runs, {len(MONITOR_MODEL_NAMES)} monitor models in '
          f'{time.perf_counter() - t0:.0f} s -> {args.out}', file=sys.stderr)
    for m, th in out['thresholds'].items():
        print(f'{m:22s} ' + '  '.join(f'{k} {v:.3g}' for k, v in th.items() if k != 'window'))


if __name__ == '__main__':
    main()
