"""The built-in monitor with its calibrated thresholds, scored on flights and units the
calibration (bench/calibrate_monitor.py) never saw: false alarms of healthy HD units on every
built-in scenario, chirps and random steps of other seeds and ranges, nuisance at 1.5 x the
documented spread and noise 0.5-2 x the documented level; detections of each
catalog fault at its alarm severity and of a 3 x leakage on the paper scenario.

    .venv/bin/python bench/bench_monitor.py [--units 6] [--seed 101] [--models SQ,C2]
"""

import argparse
import sys
import time

import numpy as np

from servovalve_twin.config import builtin_scenarios, load_scenario
from servovalve_twin.physics.faults import FAULTS
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics.calibration_set import NOISE, VARY
from servovalve_twin.prognostics.monitor import ERROR, WARN, monitor_run
from servovalve_twin.prognostics.thresholds import chirp, random_steps
from servovalve_twin.prognostics.sweep import draw_nuisance, measured
from servovalve_twin.runs import simulate


def flights(seed: int) -> dict:
    out = {n: n for n in builtin_scenarios()}
    for f0, f1, amp, load in ((0.2, 5.0, 0.03, -3000.0), (2.0, 30.0, 0.005, 6000.0)):
        c = chirp(f0, f1, amp, 2.0, load)
        out[c['name']] = c
    for k in range(4):
        out[f'steps_{seed + k}'] = random_steps(seed + k)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--units', type=int, default=6, help='healthy units per flight')
    ap.add_argument('--seed', type=int, default=101)
    ap.add_argument('--models', default='SQ,C2')
    args = ap.parse_args()
    models = args.models.split(',')
    sys.path.insert(0, 'bench')
    from bench_physics import machine
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    fl = flights(args.seed)
    alarms = {m: {'warn': 0, 'error': 0, 'runs': 0, 'where': set()} for m in models}
    for name, spec in fl.items():
        scn = load_scenario(spec)
        for _ in range(args.units):
            unit = DEFAULTS.replace(**draw_nuisance(rng, {k: 1.5 * v for k, v in VARY.items()},
                                                    DEFAULTS))
            run = simulate('HD', scn, params=unit.replace(**dict(scn.params)), ecu_period=1e-3)
            gain = float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
            run.signals.update(measured(run.signals, {k: gain * v for k, v in NOISE.items()},
                                        rng))
            for m in models:
                mon = monitor_run(run, m, nominal=DEFAULTS.replace(**dict(scn.params)))
                a = alarms[m]
                a['runs'] += 1
                a['warn'] += mon.first_alarm(WARN) is not None
                if mon.first_alarm(ERROR) is not None:
                    a['error'] += 1
                    a['where'].add(name)
    paper = load_scenario('paper').to_dict()
    cases = [(f, FAULTS[f].demo) for f in FAULTS] + [('leakage_growth', 3.0)]
    detect = {m: {} for m in models}
    for f, sev in cases:
        run = simulate('HD', dict(paper, faults=[dict(at=0.1, fault=f, severity=sev)]),
                       ecu_period=1e-3)
        run.signals.update(measured(run.signals, NOISE, rng))
        for m in models:
            mon = monitor_run(run, m, nominal=DEFAULTS)
            detect[m][f'{f} {sev:g}'] = mon.first_alarm(ERROR)
    print(f'machine: {machine()}; {len(fl)} flights ({", ".join(fl)}) x {args.units} healthy HD '
          f'units, nuisance x1.5 the documented spread, noise 0.5-2 x the documented level; '
          f'seed {args.seed}; '
          f'{time.perf_counter() - t0:.0f} s')
    print('\n| monitor model | healthy runs | ERROR (false alarms) | WARN | faults at their alarm '
          'severity detected (ERROR), paper | 3 x leakage, paper |')
    print('|---|---|---|---|---|---|')
    for m in models:
        a = alarms[m]
        d = detect[m]
        hits = [k for k, v in d.items() if v is not None and not k.startswith('leakage_growth 3')]
        miss = [k.split()[0] for k, v in d.items() if v is None
                and not k.startswith('leakage_growth 3')]
        lk = d['leakage_growth 3']
        print(f'| {m} | {a["runs"]} | {a["error"]}' + (f' ({", ".join(sorted(a["where"]))})'
                                                       if a['where'] else '')
              + f' | {a["warn"]} | {len(hits)}/{len(hits) + len(miss)}'
              + (f' (missed: {", ".join(miss)})' if miss else '')
              + f' | {"ERROR at %.3f s" % lk if lk is not None else "not detected"} |')


if __name__ == '__main__':
    main()
