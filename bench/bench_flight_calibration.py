"""Diagnosis on flights and designs of a user's own, calibrated on demand, scored on units the
calibration never saw -- against the packaged calibration on the same units.

For each flight x design (``--cases``): ``calibrate-diagnosis`` on it (seeded HD units, seed
``--cal-seed``, ``--units`` per fault and level), then test units with other seeds: healthy
ones (``--healthy`` per case) and each catalog fault at a severity drawn beyond the flight's
own verdict floor (between its detection limit on the flight -- the calibration's
``revealed_from`` -- or 1.25 x the floor's severity in ``g``, whichever is larger, and the
alarm value; ``--faulty`` per fault), nuisance within 1.5 x the documented spread and noise
0.5-2 x. Each is diagnosed twice with SQ, M and CJ free: with the flight's calibration, and
with the packaged one (what a user had before). Reported: false alarms on healthy units (a
fault named), faults named right above the stated limit, and 90 % interval coverage per fault;
the units of faults a flight's calibration states it does not reveal, apart.

The flights and designs are this bench's own (no calibration or other bench flies them):

- ``trapezoids``: 2 s, +-25 mm trapezoids, 4 kN opposing then 3 kN aiding;
- ``sine_load``: 1.5 s, a 0.8 Hz command (sampled every 10 ms) under a 0.4 Hz load of +-3 kN,
  19 MPa;
- ``ripple``: 1.2 s, 20 MPa with a 13 Hz +-2.5 MPa supply ripple, a step and a load;
- ``sag``: 1.5 s, the supply sagging to 14 MPa and back while holding 3.5 kN;
- ``reversals``: 1.2 s, four load reversals of +-4.5 kN at a held position;
- ``short``: 0.5 s, one step under load;
- designs: ``default``; ``large`` (jack 1.2e-3 m^2, 900 kg, 28 MPa, a wider valve w 16 mm, XSM
  0.2 mm, friction and damping x1.7, loads x1.7); ``small`` (jack 4.5e-4 m^2, 350 kg, 21 MPa,
  w 10 mm, friction and damping x0.64, loads x0.64).

    .venv/bin/python bench/bench_flight_calibration.py [--cases trapezoids:default,...]
        [--units 3] [--healthy 8] [--faulty 1] [--cal-seed 0] [--seed 500] [--json F] [--doc]

Seeds: calibration units come from ``--cal-seed`` (0: what ``calibrate-diagnosis`` uses),
test units from ``--seed`` (never a calibration's).
"""

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from servovalve_twin.config import load_scenario
from servovalve_twin.physics.faults import FAULTS
from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics.calibration_set import from_g, to_g, unit_signals
from servovalve_twin.prognostics.diagnosis import DIAGNOSABLE, HEALTHY, diagnose
from servovalve_twin.prognostics.flight_calibration import OWN, calibrate_flight, unit_seed


def _sine(t0, n, dt, amp, hz):
    return [[round(t0 + i * dt, 4), round(amp * math.sin(2 * math.pi * hz * i * dt), 6)]
            for i in range(n)]


FLIGHTS = {
    'trapezoids': dict(duration=2.0, com=[[0.0, 0.0], [0.1, 0.0125], [0.2, 0.025], [0.8, 0.0125],
                                          [0.9, -0.0125], [1.0, -0.025], [1.6, -0.0125],
                                          [1.7, 0.0]],
                       fr=[[0.0, 4000.0], [1.0, -3000.0]], psr=[[0.0, 2.0e7]]),
    'sine_load': dict(duration=1.5, com=_sine(0.0, 150, 0.01, 0.02, 0.8),
                      fr=_sine(0.0, 30, 0.05, 3000.0, 0.4), psr=[[0.0, 1.9e7]]),
    'ripple': dict(duration=1.2, com=[[0.0, 0.0], [0.05, 0.02], [0.6, -0.015]],
                   fr=[[0.0, 0.0], [0.3, 3000.0]],
                   psr=[[round(i / 26.0, 4), 2.0e7 + (2.5e6 if i % 2 else -2.5e6)]
                        for i in range(32)]),
    'sag': dict(duration=1.5, com=[[0.0, 0.0], [0.05, 0.02], [0.9, -0.01]],
                fr=[[0.0, 0.0], [0.2, 3500.0]],
                psr=[[0.0, 2.0e7], [0.4, 1.7e7], [0.5, 1.4e7], [0.8, 1.7e7], [0.9, 2.0e7]]),
    'reversals': dict(duration=1.2, com=[[0.0, 0.0], [0.05, 0.015]],
                      fr=[[0.0, 0.0], [0.25, 4500.0], [0.45, -4500.0], [0.65, 4500.0],
                          [0.85, -4500.0]], psr=[[0.0, 2.0e7]]),
    'short': dict(duration=0.5, com=[[0.0, 0.0], [0.05, 0.02]],
                  fr=[[0.0, 0.0], [0.2, 3000.0]], psr=[[0.0, 2.0e7]]),
}

_D = DEFAULTS
DESIGNS = {
    'default': (DEFAULTS, 1.0, 1.0),
    'large': (DEFAULTS.replace(AJ=1.2e-3, M=900.0, PSRN=2.8e7, w=0.016, XSM=2.0e-4,
                               FSJ=_D.FSJ * 1.7, FDJ=_D.FDJ * 1.7, CJ=_D.CJ * 1.7), 1.7, 1.4),
    'small': (DEFAULTS.replace(AJ=4.5e-4, M=350.0, PSRN=2.1e7, w=0.010,
                               FSJ=_D.FSJ * 0.64, FDJ=_D.FDJ * 0.64, CJ=_D.CJ * 0.64), 0.64,
              1.05),
}


def flight_of(name: str, design: str) -> dict:
    """The flight with its loads scaled to the design's jack and its supply to the design's."""
    f = json.loads(json.dumps(FLIGHTS[name]))
    _, load, supply = DESIGNS[design]
    f['fr'] = [[t, v * load] for t, v in f['fr']]
    f['psr'] = [[t, v * supply] for t, v in f['psr']]
    return load_scenario(dict(f, name=f'{name}_{design}')).to_dict()


def test_jobs(cal, healthy: int, faulty: int, seed: int) -> list[tuple]:
    """(fault or None, severity, unit seed, whether above the stated limit) of the test units.
    A fault the flight reveals (its calibration's ``revealed_from``) is drawn between that
    limit (and 1.25 x the verdict floor) and its alarm value, in ``g``: the claim "named above
    the stated limit"; one it does not reveal, between 1.25 x the floor and the alarm value:
    reported, not claimed (the calibration said "not revealed")."""
    jobs = [(None, 0.0, unit_seed(seed, None, 0.0, r), False) for r in range(healthy)]
    u = cal['verdict_fraction']
    for fault in DIAGNOSABLE:
        spec = FAULTS[fault]
        g_alarm = to_g(fault, spec.demo)
        limit = cal.get('revealed_from', {}).get(fault)
        lo = min(1.25 * u, 0.9) if limit is None else max(
            abs(to_g(fault, limit) / g_alarm), min(1.25 * u, 0.9))
        for r in range(faulty):
            k = unit_seed(seed, fault, 1.0, r)
            frac = np.random.default_rng(k).uniform(lo, 1.0)
            jobs.append((fault, float(from_g(fault, frac * g_alarm)), k, limit is not None))
    return jobs


def one(args):
    (fault, sev, seed, stated), flight, design, cal = args
    sig, truth, _ = unit_signals(fault, 1.0, flight, seed, spread=1.5, design=design,
                                 severity=sev if fault else None)
    out = {}
    for how, c, scen in (('own', cal, OWN), ('packaged', None, None)):
        d = diagnose(sig, design, control_period=1e-3, model='SQ', free=['M', 'CJ'],
                     calibration=c, scenario=scen)
        name = d.verdict or d.best.fault
        iv = d.best.interval if name == fault else None
        out[how] = dict(named=name, severity=d.best.severity,
                        held=None if iv is None or isinstance(iv, list) else
                        bool(iv[0] <= truth <= iv[1]))
    return dict(fault=fault, truth=truth, stated=stated, **out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--cases', default='trapezoids:default,sine_load:default,ripple:default,'
                    'sag:default,reversals:default,short:default,trapezoids:large,'
                    'reversals:small')
    ap.add_argument('--units', type=int, default=3)
    ap.add_argument('--healthy', type=int, default=8)
    ap.add_argument('--faulty', type=int, default=1)
    ap.add_argument('--cal-seed', type=int, default=0)
    ap.add_argument('--seed', type=int, default=500)
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--json')
    ap.add_argument('--doc', action='store_true',
                    help='write the tables into doc/results/diagnosis.md (section '
                         'flight_calibration) and the JSON into doc/results/data/')
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows, cals = [], {}
    for case in args.cases.split(','):
        name, design_name = case.split(':')
        flight = flight_of(name, design_name)
        design = DESIGNS[design_name][0]
        tc = time.perf_counter()
        cal, path = calibrate_flight(flight, design, free=('M', 'CJ'), units=args.units,
                                     seed=args.cal_seed, workers=args.workers)
        cal_s = time.perf_counter() - tc
        cals[case] = dict(verdict_fraction=cal['verdict_fraction'], seconds=cal_s,
                          healthy_units=cal['healthy_units'],
                          hidden=[f for f, v in cal['revealed_from'].items() if v is None])
        jobs = [(j, flight, design, cal) for j in test_jobs(cal, args.healthy, args.faulty,
                                                           args.seed)]
        with ProcessPoolExecutor(args.workers) as ex:
            for r in ex.map(one, jobs):
                rows.append(dict(r, case=case))
        print(f'{case}: calibrated in {cal_s:.0f} s (floor {cal["verdict_fraction"]:.3f} of '
              f'the way, {cal["healthy_units"]} healthy units); tested {len(jobs)} units',
              file=sys.stderr, flush=True)
    data = dict(args=vars(args), calibrations=cals, units=rows,
                seconds=time.perf_counter() - t0)
    print(render(data))
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(data, fh, indent=1, default=float)
    if args.doc:
        import results
        results.write(results.ROOT / 'doc' / 'results' / 'diagnosis.md', 'flight_calibration',
                      data, render(data))


def render(data) -> str:
    """The bench's tables (markdown) from its JSON (``data``: args, calibrations, units,
    seconds)."""
    args, cals, rows = data['args'], data['calibrations'], data['units']
    out = [f'cases {args["cases"]}; calibration {args["units"]} units per fault and level '
           f'(seed {args["cal_seed"]}); test units seed {args["seed"]}: {args["healthy"]} '
           f'healthy and {args["faulty"]} per fault per case; {data["seconds"]:.0f} s', '',
           '| case | floor (of the way) | not revealed | calibration [s] |', '|---|---|---|---|']
    for case, c in cals.items():
        out.append(f'| {case} | {c["verdict_fraction"]:.3f} | {", ".join(c["hidden"]) or "-"} '
                   f'| {c["seconds"]:.0f} |')
    out += ['', '| calibration | healthy units named a fault | faults above the stated limit '
            'named right | 90 % intervals hold the truth |', '|---|---|---|---|']
    h = [r for r in rows if r['fault'] is None]
    f = [r for r in rows if r['fault'] is not None and r['stated']]
    for how in ('own', 'packaged'):
        alarms = sum(r[how]['named'] != HEALTHY for r in h)
        named = sum(r[how]['named'] == r['fault'] for r in f)
        held = [r[how]['held'] for r in f if r[how]['held'] is not None]
        out.append(f'| {how} | {alarms}/{len(h)} | {named}/{len(f)} | '
                   f'{sum(held)}/{len(held)} |')
    out += ['', 'Per fault, with the flight\'s own calibration (units above the stated limit; '
            'then those of flights whose calibration states the fault not revealed):', '',
            '| fault | units | named right | intervals hold | verdicts when not named | '
            'not revealed: units, named |', '|---|---|---|---|---|---|']
    for fault in DIAGNOSABLE:
        f = [r for r in rows if r['fault'] == fault and r['stated']]
        hid = [r for r in rows if r['fault'] == fault and not r['stated']]
        held = [r['own']['held'] for r in f if r['own']['held'] is not None]
        other = sorted({r['own']['named'] for r in f if r['own']['named'] != fault})
        out.append(f'| {fault} | {len(f)} | {sum(r["own"]["named"] == fault for r in f)} | '
                   f'{sum(held)}/{len(held)} | {", ".join(other) or "-"} | '
                   f'{len(hid)}, {sum(r["own"]["named"] == fault for r in hid)} |')
    return '\n'.join(out) + '\n'


if __name__ == '__main__':
    main()
