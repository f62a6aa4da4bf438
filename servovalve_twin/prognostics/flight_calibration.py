"""Diagnosis calibrated on the flight and the design at hand, on demand.

Why. A conformal interval (and a false-alarm rate) is valid for units exchangeable with the
calibration units. The packaged calibration flew units of the default design on four flights;
on a flight or an actuator of a user's own, SQ's model-form error is another, and the trust did
not transfer (every healthy unit of a trapezoid flight was named a supply loss; a larger
actuator's healthy unit a gain loss). The way to make a unit exchangeable with the calibration
units is to fly the calibration units on that very flight and design: this module does, and
caches the result under a key of everything it depends on.

What is flown (:func:`jobs`): seeded HD units of the design, nuisance M, CJ, FDJ within 1.5 x
the documented spread and sensor noise 0.5-2 x the documented level (as the packaged
calibration's, :func:`.calibration_set.unit_signals`): ``units`` per catalog fault a simplified
model can see and per level (0.3, 0.6, 1 of the way to its alarm value), and ``2 * units *
len(LEVELS)`` healthy ones. Each unit's seed comes from (seed, fault, level, replicate) alone,
so that adding a fault or units adds those units only.

What is fitted (:func:`fit`), from their diagnoses with the model and free nuisance asked for:

- the model-form bias and spread per fault at the split-conformal rank, by the packaged
  calibration's method (:func:`.calibration.fit_calibration`), as the flight's own entry
  (``own``);
- the verdict floor (``verdict_fraction``): the largest size -- as a fraction of the way to its
  alarm value in its coordinate ``g``, the size the verdict would state, less the bias above
  (:func:`stated_sizes`) -- of the fault any healthy unit of this flight would have been
  named with: the best-scoring hypothesis where that is a fault scoring better than healthy
  (0 where healthy scores best). ``diagnose`` names a run's best-scoring fault only
  beyond it (and says healthy otherwise: healthy, or below what this flight can show); by
  exchangeability a healthy unit of this flight and design is named a fault with probability
  at most ``1/(n + 1)`` (n healthy units) -- a test with a stated false-alarm rate, in place of
  a fixed fraction of the way to the alarm value. Per fault, that fraction of the way is the
  flight's verdict floor (``healthy_floor``, in ``g``);
- the detection limit per fault (``revealed_from``): the lowest level from which every unit of
  the fault, at that level and at each one above it, was named right (its best-scoring
  hypothesis the fault, beyond the verdict floor) -- as a severity; None where even the units
  at the alarm value were not all named: the flight does not reveal that fault (fly the
  built-in test). A severity below it may be called healthy: what this flight can show.

:func:`calibrate_flight` runs the units in a process pool (progress on a terminal), appends
each finished unit to a ``.partial.jsonl`` beside the cache entry (Ctrl-C keeps them; a rerun
resumes), and writes the entry atomically. ``diagnose`` finds it by the same key
(:func:`cached`).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from ..errors import TwinError
from ..outputs import output_file
from ..physics.faults import FAULTS
from ..physics.params import EhaParams
from .calibration import fit_calibration
from .calibration_set import LEVELS, severity_at, to_g, unit_record, unit_signals
from .conformal import ALPHA, quantile
from .modelform import reported_severity
from .parallel import map_unordered
from .rules import fraction

#: the method's version: a cache entry of another is not read (its key differs)
VERSION = 5
#: the units per fault and level (the healthy ones: twice as many per level)
DEFAULT_UNITS = 3
#: the nuisance spread of the units, as a multiple of the documented one
SPREAD = 1.5
#: the calibration entry name of a flight's own units
OWN = 'own'
#: where the cache lives: this variable, else $XDG_CACHE_HOME/servovalve_twin, else
#: ~/.cache/servovalve_twin
CACHE_ENV = 'SERVOVALVE_TWIN_CACHE'


def cache_dir() -> Path:
    base = os.environ.get(CACHE_ENV)
    if not base:
        xdg = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'),
                                                               '.cache')
        base = os.path.join(xdg, 'servovalve_twin')
    return Path(base) / 'diagnosis'


def _inputs(scenario: Mapping[str, Any]) -> dict[str, Any]:
    """What of a scenario the units fly: its duration and inputs (a name or windows do not
    change the flight)."""
    return {k: scenario.get(k) for k in ('duration', 'com', 'fr', 'psr')}


def flight_key(scenario: Mapping[str, Any], design: EhaParams, model: str,
               free: Sequence[str], control_period: float, alpha: float = ALPHA) -> str:
    """The cache key: a digest of the flight's inputs, the design (every parameter, derived
    ones resolved), the fitted model, the free nuisance, the control period, the intervals'
    miscoverage ``alpha`` and :data:`VERSION` -- what a diagnosis of a run can know of it; the
    units and seed it was computed with are in its ``about``."""
    payload = json.dumps(dict(version=VERSION, inputs=_inputs(scenario),
                              design=design.resolved(), model=model, free=sorted(free),
                              control_period=float(control_period), alpha=float(alpha)),
                         sort_keys=True, default=float)
    return hashlib.sha256(payload.encode()).hexdigest()[:24]


def unit_seed(seed: int, fault: str | None, level: float, replicate: int) -> int:
    """A unit's seed from what it is alone (adding a fault re-seeds no other unit)."""
    text = f'{seed}/{fault or "healthy"}/{level:.6g}/{replicate}'
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], 'little') >> 1


def jobs(faults: Sequence[str], units: int, seed: int) -> list[tuple]:
    """(fault or None, level, replicate, seed) of every unit (module docstring)."""
    out = [(None, 0.0, r, unit_seed(seed, None, 0.0, r))
           for r in range(2 * units * len(LEVELS))]
    for fault in faults:
        for q in LEVELS:
            out += [(fault, q, r, unit_seed(seed, fault, q, r)) for r in range(units)]
    return out


def _job_id(job: tuple) -> str:
    fault, q, r, seed = job
    return f'{fault or "healthy"}/{q:g}/{r}/{seed}'


def run_unit(job: tuple, scenario: Mapping[str, Any], design: EhaParams, model: str,
             free: Sequence[str], control_period: float, faults: Sequence[str]
             ) -> dict[str, Any]:
    """One unit flown and diagnosed (without a model-form calibration): the record
    :func:`fit` needs -- its truth, the verdict, the right hypothesis' estimate and standard
    error in ``g``, its fit's RMS, and every single fault's fitted ``g`` (the healthy units'
    set the verdict floor)."""
    from .diagnosis import HEALTHY, diagnose
    fault, q, _, seed = job
    sig, truth, _ = unit_signals(fault, q, dict(scenario), seed, spread=SPREAD, design=design)
    # (the second-fault screen only makes a verdict unexplained, which no record reads: 12 %
    # of a unit's time on the trapezoid flight, measured)
    d = diagnose(sig, design, control_period=control_period, model=model, faults=faults,
                 free=free, model_form=False, second_fault=False)
    healthy = next(c for c in d.candidates if c.fault == HEALTHY)
    top = min(d.candidates, key=lambda c: c.score)
    # the fault this unit would be named with, whatever the floor: the best-scoring
    # hypothesis where it is a fault scoring better than healthy, as fitted (:func:`fit`
    # sizes it as the verdict would state it, once the flight's bias is known)
    best = None if top.fault == HEALTHY or len(top.faults) != 1 or \
        top.score >= healthy.score else [top.fault, float(top.severities[0])]
    return dict(unit_record(d, fault, truth), id=_job_id(job), level=q, scenario=OWN,
                best=best)


def verdict_fraction(records: Iterable[Mapping[str, Any]]) -> float:
    """The verdict floor (module docstring): the largest fraction of the way to its alarm
    value of the fault any healthy unit would have been named with; 0 where none would --
    the conformal quantile at ``alpha = 1/(n + 1)`` of the healthy units' scores (their best
    fault's fraction, 0 for those healthy scored best), the one that bounds the false-alarm
    rate of a new healthy unit by ``1/(n + 1)``."""
    healthy = [r for r in records if r['fault'] is None]
    if not healthy:
        raise TwinError('a flight calibration needs healthy units')
    scores = [r['best'][1] if r.get('best') else 0.0 for r in healthy]
    return quantile(scores, 1.0 / (len(scores) + 1))


def revealed_from(records: Iterable[Mapping[str, Any]], fault: str, u: float
                  ) -> float | None:
    """The fault's detection limit on this flight (module docstring), as a level of the way
    to its alarm value; None: not revealed. A unit is named right when its best-scoring
    hypothesis (``best``) is its own fault, beyond the verdict floor ``u`` -- the rule
    ``diagnose`` applies with this calibration. Walked down from the alarm value: one miss at a
    level ends the walk, so a limit never stands on units that were named above a miss."""
    units: dict[float, list[bool]] = {}
    for r in records:
        if r['fault'] == fault:
            units.setdefault(r['level'], []).append(
                bool(r.get('best')) and r['best'][0] == fault and r['best'][1] > u)
    found = None
    for q in sorted(units, reverse=True):
        if not all(units[q]):
            break
        found = q
    return found


def stated_sizes(records: Iterable[Mapping[str, Any]], cal: Mapping[str, Any]
                 ) -> list[dict[str, Any]]:
    """``records`` with each ``best`` (a fault and its fitted severity) as the fault and the
    fraction of the way to its alarm value of the size ``diagnose`` would state with ``cal``
    (:func:`.modelform.reported_severity`, the flight's own entry): the floor and the verdict
    then test one statistic. (The floor read fitted sizes while the verdict stated corrected
    ones: 2 of 104 healthy units of the bench were named a gain loss stated at 0.0.)"""
    out = []
    for r in records:
        best = r.get('best')
        if best:
            f, s = best
            best = [f, fraction(f, reported_severity(cal, f, s, OWN))]
        out.append(dict(r, best=best))
    return out


def fit(records: Sequence[Mapping[str, Any]], faults: Sequence[str], alpha: float = ALPHA,
        model: str | None = None, free: Sequence[str] = ()) -> dict[str, Any]:
    """The calibration entry of a flight from its units' records, its intervals at
    miscoverage ``alpha``; ``model`` and ``free``: the fit's, whose packaged pooled entries
    ``diagnose`` applies beside the flight's own (:func:`with_pooled`; None: none)."""
    cal = fit_calibration(records, alpha=alpha)
    records = stated_sizes(records, with_pooled(cal, model, free) if model else cal)
    u = verdict_fraction(records)
    cal['verdict_fraction'] = u
    cal['healthy_floor'] = {f: u * abs(to_g(f, FAULTS[f].demo)) for f in faults}
    cal['healthy_units'] = sum(1 for r in records if r['fault'] is None)
    levels = {f: revealed_from(records, f, u) for f in faults}
    cal['revealed_from'] = {f: None if q is None else severity_at(f, q)
                            for f, q in levels.items()}
    return cal


def with_pooled(cal: dict[str, Any], model: str, free: Sequence[str]) -> dict[str, Any]:
    """The flight's calibration as ``diagnose`` applies it: its own entry (``by_scenario``
    ``'own'``) beside the packaged calibration's pooled one (``faults``, many flights and
    units), so that :func:`.calibration.fault_calibration`'s declared rule holds -- a flight's
    own spread stands alone only on :data:`.calibration.OWN_UNITS` units, else the larger of
    it and the pooled one: from the 9 units of 3 per level it is itself uncertain (a spread of
    0 where all 9 fell inside their noise intervals: on the bench's own flights the intervals
    held 26 of 44 test units so, 35 of 44 with the packaged calibration alone)."""
    from .calibration import calibration_for
    packaged = calibration_for(model, free)
    if not packaged:
        return cal
    return dict(cal, faults=packaged['faults'])


def entry_path(key: str) -> Path:
    return cache_dir() / f'{key}.json'


def cached(key: str) -> dict[str, Any] | None:
    """The cached calibration of ``key``, or None. An entry that is not this version's
    JSON is named in one line, never read silently."""
    path = entry_path(key)
    if not path.is_file():
        return None
    try:
        cal = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        raise TwinError(f'{path} is not a flight calibration (damaged?): remove it and '
                        'calibrate again') from None
    if not isinstance(cal, dict) or cal.get('about', {}).get('version') != VERSION:
        raise TwinError(f'{path} was written by another version of the flight calibration; '
                        'remove it and calibrate again')
    return cal


def _unit(args):
    return run_unit(*args)


def calibrate_flight(scenario: Mapping[str, Any], design: EhaParams, *, model: str = 'SQ',
                     free: Sequence[str] = (), control_period: float = 1e-3,
                     faults: Sequence[str] | None = None, units: int = DEFAULT_UNITS,
                     seed: int = 0, workers: int | None = None, alpha: float = ALPHA,
                     scheduler: str | None = None) -> tuple[dict[str, Any], Path]:
    """The flight's calibration (cached, or computed and cached): (entry, its path). The units
    run on ``workers`` local processes (default: one per core), or on the Dask cluster at
    ``scheduler``, and are kept as each finishes."""
    from ..progress import progress
    from .rules import DIAGNOSABLE
    faults = list(DIAGNOSABLE if faults is None else faults)
    if not 1 <= units <= 100:
        raise TwinError(f'units must be 1 to 100 per fault and level, got {units}')
    key = flight_key(scenario, design, model, free, control_period, alpha)
    have = cached(key)
    path = entry_path(key)
    about = (have or {}).get('about', {})
    if have is not None and (about.get('units'), about.get('seed'), about.get('faults')) == (
            units, seed, faults):
        return with_pooled(have, model, free), path
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix('.partial.jsonl')
    done: dict[str, dict] = {}
    if partial.is_file():
        for line in partial.read_text(encoding='utf-8').splitlines():
            try:
                rec = json.loads(line)
                done[rec['id']] = rec
            except (json.JSONDecodeError, KeyError, TypeError):
                continue                        # a line cut by a kill: run that unit again
    todo = [j for j in jobs(faults, units, seed) if _job_id(j) not in done]
    args = [(j, dict(scenario), design, model, tuple(free), control_period, tuple(faults))
            for j in todo]
    with open(partial, 'a', encoding='utf-8') as out:
        # (a unit takes ~1 s: one per Dask task costs ~2 % of it)
        stream = map_unordered(_unit, args, workers=workers, scheduler=scheduler)
        for rec in progress(stream, total=len(todo), desc='calibrate', unit='unit'):
            done[rec['id']] = rec
            out.write(json.dumps(rec) + '\n')
            out.flush()
    # (in the units' order, not as they finished: the same units give the same entry)
    cal = fit([done[k] for k in sorted(done)], faults, alpha, model, free)
    cal['about'] = dict(version=VERSION, key=key, model=model, free=sorted(free),
                        units=units, seed=seed, faults=faults, spread=SPREAD, alpha=alpha,
                        levels=list(LEVELS), inputs=_inputs(scenario),
                        design={k: v for k, v in design.resolved().items()})
    with output_file(path) as fh:
        fh.write(json.dumps(cal, default=float) + '\n')
    partial.unlink(missing_ok=True)
    return with_pooled(cal, model, free), path


__all__ = ['calibrate_flight', 'flight_key', 'cached', 'with_pooled', 'jobs', 'unit_seed',
           'verdict_fraction', 'revealed_from', 'stated_sizes', 'fit', 'cache_dir', 'VERSION',
           'OWN']
