"""Rebuild the packaged model-form calibration of diagnosis
(``servovalve_twin/data/diagnosis_calibration.json``; what it holds and why:
:mod:`servovalve_twin.prognostics.calibration`).

Every unit of the calibration set (seeded: --seed) is diagnosed with SQ against the design,
without the model-form term, once with M and CJ free and once without; so are the onset units
(on the paper flight and the built-in test), with the onset fitted; the per-fault bias and
spread, the onset intervals' factor and the goodness-of-fit reference are fitted to the
results. Runs in a process pool.

    .venv/bin/python bench/calibrate_diagnosis.py [--units 3] [--seed 7] [--out FILE]
        [--onset-units 12] [--refit | --reuse | --onset-only]
"""

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

from servovalve_twin.physics.params import DEFAULTS
from servovalve_twin.prognostics.calibration import CALIBRATION_FILE, fit_calibration
from servovalve_twin.prognostics.calibration_set import (CAL_SCENARIOS, LEVELS, EXTRA_UNITS, NOISE,
                                                         ONSET_EXTRA, ONSET_SCENARIOS, ONSET_UNITS,
                                                         ONSET_WINDOW, PAST_ONSET_UNITS, PAST_UNITS,
                                                         VARY, calibration_jobs, onset_jobs,
                                                         unit_record, unit_signals, widen_needed)
from servovalve_twin.prognostics.diagnosis import diagnose

FREE_SETS = (('CJ', 'M'), ())
#: the nuisance of the calibration units, as a multiple of the documented spread: the domain a
#: calibrated interval claims (the bench scores it on other seeds and another scenario)
SPREAD = 1.5


def record(d, fault, truth):
    """What the calibration needs of one diagnosis (calibration_set.unit_record)."""
    return unit_record(d, fault, truth)


def _stale(r) -> bool:
    """A kept unit's diagnoses recorded before every fault unit's record held its right
    hypothesis' estimate (named or not), or an onset unit's before its onset cost was kept:
    diagnosed again."""
    return any(v['fault'] is not None and 'estimate' not in v
               or v.get('refitted') and 'profile' not in v for v in r.values())


def one(job):
    fault, q, scen, seed = job
    sig, truth, _ = unit_signals(fault, q, CAL_SCENARIOS[scen], seed, spread=SPREAD)
    return {free: dict(record(diagnose(sig, DEFAULTS, control_period=1e-3, model='SQ',
                                       free=free, model_form=False), fault, truth),
                       scenario=scen) for free in FREE_SETS}


def one_onset(job):
    """An onset unit (calibration_set.onset_jobs), diagnosed with the onset fitted."""
    fault, q, scen, seed, at = job
    sig, truth, _ = unit_signals(fault, q, CAL_SCENARIOS[scen], seed, spread=SPREAD, onset=at)
    out = {}
    for free in FREE_SETS:
        d = diagnose(sig, DEFAULTS, control_period=1e-3, model='SQ', free=free,
                     model_form=False, onset=True)
        refitted = bool(d.onset and not d.onset.get('from_start'))
        # the onset's cost per tried instant is kept, not only the factor it needs: a change
        # to how an interval is read from it is then a --refit, not an hour of diagnoses
        profile = None if not refitted else dict(
            costs=sorted([float(t), float(c)] for t, c in d.onset_profile['costs'].items()),
            rss=d.onset_profile['rss'], width=d.onset_profile['width'], window=list(d.window))
        out[free] = dict(record(d, fault, truth), scenario=scen, onset=at, refitted=refitted,
                         profile=profile)
    return out


def with_widen(r):
    """An onset unit's record with the factor its interval needs (:func:`widen_needed` of
    its kept profile; None where the answer was not refitted at an onset)."""
    p = r.get('profile')
    return dict(r, widen=None if p is None else widen_needed(
        dict(p, costs=dict(p['costs'])), tuple(p['window']), r['onset']))


def _keyed(results):
    return [{json.dumps(list(k)): v for k, v in r.items()} for r in results]


def _unkeyed(kept):
    return [{tuple(json.loads(k)): v for k, v in r.items()} for r in kept]


def _key(job) -> str:
    return json.dumps(list(job))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--units', type=int, default=3,
                    help='units per fault, level, scenario (the packaged calibration: 3)')
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--out', default=str(CALIBRATION_FILE))
    ap.add_argument('--records', default='out/calibration_records.json',
                    help='where the diagnosed units are kept (the expensive part)')
    ap.add_argument('--onset-units', type=int, default=ONSET_UNITS,
                    help='onset units per fault (calibration_set.onset_jobs)')
    ap.add_argument('--refit', action='store_true',
                    help='fit the calibration again from --records, diagnosing nothing')
    ap.add_argument('--reuse', action='store_true',
                    help='diagnose only the units --records lacks (units added to the set, '
                    'or recorded by an older bench)')
    ap.add_argument('--onset-only', action='store_true',
                    help='diagnose the onset units again, the other units taken from --records')
    args = ap.parse_args()
    jobs = calibration_jobs(args.units, args.seed)
    ojobs = onset_jobs(args.onset_units, args.seed)
    t0 = time.perf_counter()
    kept, okept = {}, {}
    if args.refit or args.reuse or args.onset_only:
        with open(args.records, encoding='utf-8') as fh:
            rec = json.load(fh)
        # each unit's diagnoses by its job (fault, level, scenario, seed[, onset]): a job of
        # the set that the records lack is diagnosed, one they hold that the set lacks unused
        kept = {_key(j): r for j, r in zip(rec['jobs'], _unkeyed(rec['results']))}
        if not args.onset_only:
            okept = {_key(j): r for j, r in zip(rec.get('onset_jobs', []),
                                                _unkeyed(rec.get('onset_results', [])))}
    todo = [j for j in jobs if _key(j) not in kept or _stale(kept[_key(j)])]
    otodo = [j for j in ojobs if _key(j) not in okept or _stale(okept[_key(j)])]
    if args.refit and (todo or otodo):
        sys.exit(f'{args.records} lacks {len(todo)} units and {len(otodo)} onset units of this '
                 'calibration set (units, seed or scenarios differ, or records of an older '
                 'bench); run with --reuse')
    with ProcessPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        unit_signals(None, 0.0, 'paper', 0)             # compile in the parent, not per worker
        kept.update(zip(map(_key, todo), pool.map(one, todo, chunksize=2)))
        okept.update(zip(map(_key, otodo), pool.map(one_onset, otodo)))
    # (records kept before the scenario was recorded in them: it is the job's)
    # (and the level: where the calibration fits it, up to the alarm value or past it)
    results = [{k: dict(v, scenario=job[2], level=job[1]) for k, v in kept[_key(job)].items()}
               for job in jobs]
    onsets = [{k: dict(v, level=job[1]) for k, v in okept[_key(job)].items()} for job in ojobs]
    if not args.refit:
        os.makedirs(os.path.dirname(args.records) or '.', exist_ok=True)
        with open(args.records, 'w', encoding='utf-8') as fh:
            json.dump(dict(jobs=jobs, results=_keyed(results), onset_jobs=ojobs,
                           onset_results=_keyed(onsets)), fh)
    out = dict(about=dict(model='SQ', plant='HD', seed=args.seed, units=args.units,
                          extra_units=EXTRA_UNITS, past_units=PAST_UNITS,
                          past_onset_units=PAST_ONSET_UNITS,
                          scenarios=sorted(CAL_SCENARIOS), levels=list(LEVELS), vary=VARY,
                          spread=SPREAD, onset_units=args.onset_units,
                          onset_extra=ONSET_EXTRA,
                          onset_window=list(ONSET_WINDOW),
                          onset_scenarios=list(ONSET_SCENARIOS),
                          noise=NOISE, noise_gain='log-uniform 0.5-2',
                          diagnoses=len(jobs) + len(ojobs)))
    for free in FREE_SETS:
        out[f'SQ/{",".join(free)}'] = fit_calibration([r[free] for r in results],
                                                      [with_widen(r[free]) for r in onsets])
    with open(args.out, 'w', encoding='utf-8') as fh:
        json.dump(out, fh, indent=1, sort_keys=True)
        fh.write('\n')
    print(f'{len(jobs)} units and {len(ojobs)} onset units ({len(todo)} and {len(otodo)} '
          f'diagnosed now) x {len(FREE_SETS)} diagnoses in {time.perf_counter() - t0:.0f} s '
          f'-> {args.out}', file=sys.stderr)
    for key in (k for k in out if k != 'about'):
        print(key)
        for f, c in out[key]['faults'].items():
            print(f'  {f:24s} bias {c["bias"]:+.4f}  sigma {c["sigma"]:.4f}  named '
                  f'{c["named"]:.0%} of {c["units"]}')
        for entry in ('past', 'past_onset'):
            for f, c in out[key].get(entry, {}).items():
                print(f'  {entry:10s} {f:24s} slope {c["slope"]:+.4f}  rate {c["rate"]:.4f}  '
                      f'named {c["named"]:.0%} of {c["units"]} (scored {c["scored"]})')
        for scen, fits in out[key]['by_scenario'].items():
            for f, c in fits.items():
                shape = 'kernel      ' if c.get('points') else f'slope {c["slope"]:+.3f}'
                print(f'  on {scen:8s} {f:24s} bias {c["bias"]:+.4f} {shape} sigma '
                      f'{c["sigma"]:.4f} k {c["k"]:.2f}')
        print('  onset interval factors', {k: round(v, 2)
                                            for k, v in out[key]['onset_widen'].items()})
        print('  rms quantiles', {k: round(v, 3) for k, v in out[key]['rms_quantiles'].items()})


if __name__ == '__main__':
    main()
