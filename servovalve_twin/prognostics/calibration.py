"""The model-form calibration of diagnosis: how far a simplified model's severity estimates lie
from the truth on HD units, per fault class, and how well a right hypothesis fits -- so that
a diagnosis can state intervals that hold the truth (not only the measurement noise) and say
``unexplained`` when no hypothesis fits as a right one does.

The calibration set (:mod:`.calibration_set`, seeded): for every catalog fault a simplified
model can see, at mild, moderate and severe severities (0.3, 0.6 and 1 of the way from
healthy to the alarm value, geometrically for multipliers), and healthy units, HD actuators
with nuisance drawn within 1.5 times the documented spread (the domain a calibrated interval
claims), measured with noise scaled 0.5-2x the documented level, flying each calibration
scenario; on the built-in test and the paper flight more units at severities drawn between
the levels, and down to the verdict floor. Each is diagnosed with the model and nuisance set
calibrated.

Per fault, in the fault's own coordinate ``g`` (``ln(s/h)`` for a multiplier, ``(s - h)/span``
for a fraction or a value, ``span`` the distance from healthy to the alarm value):

- ``bias``: the median of ``g(estimate) - g(truth)`` over the units whose right hypothesis'
  fit pins the severity (their own ``se`` at most :data:`SE_PINNED`), whatever their verdict
  (over the named ones alone it is truncated at the verdict floor); on a calibration
  scenario's own entry a line in the estimate, or where extra units spread between the levels
  a kernel mean that follows it (on the built-in test SQ reads static friction 20 % low up to
  ~5 x and 10-25 % high at 20 x; on the paper flight a leak at its stated limit, 1.585 x,
  near the verdict floor, 12.6 % low, and 4 % low at 10 x, M and CJ free);
- ``sigma``: the model-form spread, set so that ``g(estimate) - bias +- z*sqrt(se^2 + sigma^2)``
  holds ``g(truth)`` in ``ceil((1 - alpha)(n + 1))`` of the ``n`` pinned units where the fault
  was named (the answers an interval is stated for; ``alpha`` 0.1, z = 1.645, ``se`` the fit's
  own standard error) -- the conformal quantile of :func:`.conformal.spread_score`, which makes
  the coverage of a new unit from the same distribution at least 1 - alpha however few the
  units, from :func:`.conformal.units_needed` on (a plain 90 % of them covered 85-88 % of new
  units: measured);
- ``k``: for the units whose fit does not pin the severity (a flat likelihood), the factor on
  their own ``se`` that holds them at the same rank, ``sqrt((k*se)^2 + sigma^2)``
  (:func:`spread_of`) -- so that a few unidentifiable units do not widen every interval;

and over the units whose right hypothesis was fitted, the distribution of the fit's RMS of
normalised residuals (``rms``): its quantiles are the goodness-of-fit reference. Units flown
past the alarm value, up to the catalog's end (:data:`.calibration_set.PAST_UNITS`,
:data:`.calibration_set.PAST_ONSET_UNITS`), are fitted apart (:func:`_fit_past`: ``past``,
``past_onset``, ``past_rms``). The result is a small JSON file packaged with the code
(``data/diagnosis_calibration.json``), rebuilt with ``bench/calibrate_diagnosis.py``; the bench
that scores diagnosis uses other seeds, other scenarios and nuisance beyond the spread.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..physics.faults import FAULTS
from .calibration_set import EXTRA_UNITS, NOISE, past_by, to_g
from .conformal import (ALPHA, factor_score, p_value, quantile, rate_score, spread_score,
                        z_of)

CALIBRATION_FILE = Path(__file__).resolve().parents[1] / 'data' / 'diagnosis_calibration.json'
#: named units of a fault on one calibration scenario needed for its own calibration entry
SCENARIO_UNITS = 6


#: a fit whose own 95 % interval is within about +-0.2 in ``g`` (``se`` <= 0.1) pins its
#: severity: its error is the model's bias and spread. A wider one is a flat likelihood
#: (static friction of 7-16 x on the built-in test: estimates off by up to 1.1 in g, se
#: ~0.35), whose error is its own interval's to hold, widened (``k``), not a spread to put on
#: every unit
SE_PINNED = 0.1
#: a fit within this fraction of the way from healthy to the alarm value sits at healthy
HEALTHY_FIT = 1e-3
#: the bandwidth in ``g`` of a bias that follows the estimate (a Gaussian kernel)
BANDWIDTH = 0.3
#: named units of a fault a scenario's own spread needs to stand alone
OWN_UNITS = 20


def _kernel(points: np.ndarray, g: float | np.ndarray, bandwidth: float = BANDWIDTH):
    """The Nadaraya-Watson mean of ``points`` (rows of (g of the estimate, error)) at ``g``."""
    w = np.exp(-0.5 * ((np.asarray(g)[..., None] - points[:, 0]) / bandwidth) ** 2) + 1e-300
    return np.sum(w * points[:, 1], axis=-1) / np.sum(w, axis=-1)


def _fit_faults(records: Sequence[Mapping[str, Any]], *, shape: str, min_units: int = 5,
                alpha: float = ALPHA) -> dict[str, Any]:
    """Per fault with at least ``min_units`` units where it was named: the bias of
    ``g(estimate) - g(truth)`` over every unit of the fault whose right hypothesis' fit pins
    the severity (:data:`SE_PINNED`; all of them if fewer than three named ones do), whatever
    its verdict, unless it sits at healthy (:data:`HEALTHY_FIT`) -- the bias is that of the
    fit, which the verdict then reads; over the named units alone it was truncated: near the
    verdict floor a unit that reads low is called healthy and left out, and a leak of 1.66 x
    on the paper flight was still called healthy against a stated limit of 1.585 x (measured)
    -- of ``shape`` 'constant' (their median), 'line' (least squares in the estimate, ``bias +
    slope*(g - g0)``, ``g0`` their mean) or 'kernel' (a Gaussian kernel mean over the
    estimate, :data:`BANDWIDTH`: a bias that changes sign with the severity; the units' points
    are kept); then, at the split-conformal rank, the model-form spread ``sigma`` from the
    deviations of the pinned units where the fault was named, the answers an interval is
    stated for (leave-one-out for a line or a kernel: fitted through few units it fits them
    better than a new one, the jackknife+ reading of conformal prediction), and the factor
    ``k`` on the other named units' own standard error (1 if none). ``units``: the named
    units; ``fitted``: the bias's."""
    out = {}
    for fault in sorted({r['fault'] for r in records if r['fault']}):
        # (a right hypothesis fitted at the healthy severity found no fault -- a supply loss
        # whose fit stayed at 0 while a leak took the run -- and says nothing of the bias of
        # one that found it)
        rows = [r for r in records if r['fault'] == fault and r.get('estimate') is not None]
        ge = np.array([to_g(fault, r['estimate']) for r in rows])
        found = np.abs(ge) > HEALTHY_FIT * abs(to_g(fault, FAULTS[fault].demo))
        rows, ge = [r for r, f in zip(rows, found) if f], ge[found]
        named = np.array([r['named'] == fault for r in rows], dtype=bool)
        if named.sum() < min_units:
            continue
        err = ge - np.array([to_g(fault, r['truth']) for r in rows])
        se = np.array([r['se'] for r in rows])
        pinned = se <= SE_PINNED
        if (pinned & named).sum() < 3:
            pinned[:] = True
        fit, scored = np.flatnonzero(pinned), np.flatnonzero(pinned & named)
        gp, ep = ge[fit], err[fit]
        entry: dict[str, Any] = dict(bias=float(np.median(ep)), slope=0.0, g0=float(np.mean(gp)))
        # each scored unit's deviation from the bias fitted without it
        loo = np.empty(len(scored))
        others = [fit != i for i in scored]
        if shape == 'line' and np.ptp(gp) > 0:
            slope, entry['bias'] = (float(v) for v in np.polyfit(gp - entry['g0'], ep, 1))
            entry['slope'] = slope
            for m, (i, keep) in enumerate(zip(scored, others)):
                k1, k0 = np.polyfit(gp[keep] - entry['g0'], ep[keep], 1)
                loo[m] = err[i] - k0 - k1 * (ge[i] - entry['g0'])
        elif shape == 'kernel' and len(gp) > 1:
            pts = np.column_stack([gp, ep])
            entry.update(points=pts.tolist(), bandwidth=BANDWIDTH)
            for m, (i, keep) in enumerate(zip(scored, others)):
                loo[m] = err[i] - _kernel(pts[keep], ge[i])
        else:
            loo = err[scored] - entry['bias']
        z = z_of(alpha)
        sigma = quantile(spread_score(loo, se[scored], z), alpha)
        k = 1.0
        loose = np.flatnonzero(~pinned & named)
        if len(loose):
            dev = err[loose] - np.array([bias_at(entry, g) for g in ge[loose]])
            # (a flat fit's own interval is never narrowed: k at least 1)
            k = max(1.0, quantile(factor_score(dev, se[loose], sigma, z), alpha))
        entry.update(sigma=sigma, k=k, units=int(named.sum()), pinned=len(scored),
                     fitted=len(fit),
                     named=int(named.sum()) / sum(1 for r in records if r['fault'] == fault))
        out[fault] = entry
    return out


def fit_calibration(records: Sequence[Mapping[str, Any]],
                    onset_records: Sequence[Mapping[str, Any]] = (), alpha: float = ALPHA
                    ) -> dict[str, Any]:
    """The calibration from diagnosed units: each record has fault, truth, named (the
    verdict), estimate, se (in g), rms (of the right hypothesis' fit) and scenario. Per fault,
    pooled over the scenarios, a constant bias and the spread (``faults``); per calibration
    scenario with at least :data:`SCENARIO_UNITS` named units of a fault, a bias linear in the
    estimate -- a kernel mean over it on a scenario of :data:`EXTRA_UNITS` -- and its spread
    (``by_scenario``): the model-form error depends on the excitation and, on the built-in
    test, on the severity (static friction read ~20 % low up to ~5 x, 10-25 % high at the
    alarm 20 x: measured); the rms quantiles. ``onset_records``: the onset units
    (:func:`onset_jobs`), those whose answer was refitted at an onset (``refitted``) giving
    the entries ``by_scenario['onset']`` (a line, pooled over the onset flights) and
    ``by_scenario['onset:<scenario>']`` (per flight, its ``scenario``), and the factor on
    their onset intervals (``onset_widen``, by the same keys, from each named unit's
    ``widen``: :func:`widen_needed`) -- and nothing else. A record whose ``level`` (its
    fraction of the way to the alarm value) is past 1 is fitted apart, into ``past`` (from
    the start) and ``past_onset`` (refitted at an onset; :func:`_fit_past`), the from-start
    ones' RMS into ``past_rms``; it enters no other entry: the model-form error grows past the
    alarm value (a leak on the paper flight: a spread of 0.004 in ``g`` up to it, 0.094 with
    the units past it folded in: measured), and one spread for both made every answer's
    interval as wide as the worst one's."""
    past_records = [r for r in records if r.get('level', 0.0) > 1.0]
    past_onset = [r for r in onset_records if r.get('level', 0.0) > 1.0 and r.get('refitted')]
    records = [r for r in records if r.get('level', 0.0) <= 1.0]
    onset_records = [r for r in onset_records if r.get('level', 0.0) <= 1.0]
    out: dict[str, Any] = {'alpha': alpha,
                           'faults': _fit_faults(records, shape='constant', alpha=alpha)}
    out['by_scenario'] = {}
    for scen in sorted({r['scenario'] for r in records if r.get('scenario')}):
        # a scenario whose units spread their severities between the levels gets a bias that
        # follows the estimate; through three levels alone a kernel would snap to them
        fits = _fit_faults([r for r in records if r.get('scenario') == scen],
                           shape='kernel' if scen in EXTRA_UNITS else 'line',
                           min_units=SCENARIO_UNITS, alpha=alpha)
        if fits:
            out['by_scenario'][scen] = fits
    # the onset answers: pooled over the onset flights (a flight without onset units of its
    # own takes these) and per flight; the factor on their onset intervals' width at the
    # split-conformal rank of the units named rightly
    refitted = [r for r in onset_records if r.get('refitted')]
    out['onset_widen'] = {}
    for key, rows in [('onset', refitted)] + [
            (f'onset:{scen}', [r for r in refitted if r.get('scenario') == scen])
            for scen in sorted({r.get('scenario') for r in refitted if r.get('scenario')})]:
        fits = _fit_faults(rows, shape='line', min_units=SCENARIO_UNITS, alpha=alpha)
        if fits:
            out['by_scenario'][key] = fits
        need = [r['widen'] for r in rows if r.get('widen') is not None
                and r['named'] == r['fault']]
        if need:
            out['onset_widen'][key] = quantile(need, alpha)
    rms = np.array([r['rms'] for r in records if r.get('rms') is not None])
    out['rms_quantiles'] = {str(q): float(np.quantile(rms, q))
                            for q in (0.5, 0.9, 0.99, 0.999, 1.0)}
    out['rms'] = sorted(float(x) for x in rms)
    if past_onset:
        # (an onset answer's error past the alarm value is its own, as up to it: its units,
        # eight per fault, are not pooled with those from the start -- read just past the
        # alarm value but far short of their truth, single ones set a growth of up to 2.0 per
        # unit of g for every answer: measured)
        out['past_onset'] = _fit_past(past_onset, out, alpha=alpha)
    if past_records:
        out['past'] = _fit_past(past_records, out, alpha=alpha)
        # the right fits past the alarm value fit worse (a torque-motor gain loss of 0.78 on
        # the built-in test: RMS 3.3-3.5 where those up to it stay within 3.0): an answer
        # past it is tested against them all (:func:`gof_reference`)
        out['past_rms'] = sorted(out['rms'] + [float(r['rms']) for r in past_records
                                               if r.get('rms') is not None])
    return out


def _fit_past(records: Sequence[Mapping[str, Any]], cal: Mapping[str, Any],
              min_units: int = SCENARIO_UNITS, alpha: float = ALPHA) -> dict[str, Any]:
    """The entries ``past`` of a calibration ``cal`` (its entries up to the alarm value
    fitted), from ``records`` of units past the alarm value (diagnosed from the start, or
    refitted at an onset: ``past_onset``): per fault with at least ``min_units`` named, over
    the units whose estimate lies past it, by ``x`` in ``g`` (one short of it is answered by
    the entries up to it), each unit's error after the correction its flight's entry would
    make (an onset unit's, its onset entry); ``slope``: the least-squares line through 0 at
    the alarm value, and ``rate``: how the spread grows with ``x``, ``sqrt(sigma^2 +
    (rate*x)^2)`` with ``sigma`` the flight's entry's, at the split-conformal rank of the
    deviations from the line (leave-one-out) -- both continuous at the alarm value, and
    growing past it (SQ reads a leak of 20 x on the paper flight 9 % low, of 60 x 23 %:
    measured). A spread that stepped
    up at the alarm value, or where the interval first lies wholly past it, widened the
    answers there as much as those at the catalog's end (the bench's intervals held 140 of
    146 for a stated 90 %, a gain loss of 0.71 answered [0.65, 0.78]). Pooled over the flights
    (two units per fault and flight)."""
    from .rules import onset_entry
    out = {}
    for fault in sorted({r['fault'] for r in records if r['fault']}):
        rows = []
        for r in records:
            if r['fault'] != fault or r.get('estimate') is None:
                continue
            scen = r.get('scenario')
            c = fault_calibration(cal, fault,
                                  onset_entry(cal, scen) if r.get('refitted') else scen)
            if c is None:
                continue
            g = to_g(fault, r['estimate'])
            x = past_by(fault, g)
            if x > 0:
                rows.append((x, g - bias_at(c, g) - to_g(fault, r['truth']),
                             spread_of(c, r['se']), r['se'] <= SE_PINNED, r['named'] == fault))
        if sum(row[-1] for row in rows) < min_units:
            continue
        x, dev, spread, pinned, named = (np.array(v) for v in zip(*rows))
        if (pinned & named).sum() < 3:
            pinned[:] = True

        def slope_of(keep: np.ndarray) -> float:
            return float(np.sum(x[keep] * dev[keep]) / np.sum(x[keep] ** 2))

        slope = slope_of(pinned)
        sc = np.flatnonzero(pinned & named)
        loo = np.array([dev[i] - slope_of(pinned & (np.arange(len(x)) != i)) * x[i]
                        for i in sc])
        rate = quantile(rate_score(loo, spread[sc], x[sc], z_of(alpha)), alpha)
        out[fault] = dict(slope=slope, rate=rate, units=int(named.sum()), scored=len(sc),
                          named=float(named.mean()))
    return out


def past_correction(cal: Mapping[str, Any], fault: str, g: float,
                    c: Mapping[str, Any], onset: bool = False
                    ) -> tuple[float, Mapping[str, Any]]:
    """For an estimate at ``g`` whose entry up to the alarm value is ``c``: the further bias
    past the alarm value, ``slope`` times how far past it the estimate lies (0 short of it, or
    without a ``past`` entry of the fault; ``onset``: an answer refitted at an onset, whose
    entry is ``past_onset`` where the calibration has one for the fault), and the entry whose
    spread the answer takes, ``c``'s grown by the ``past`` entry's ``rate`` times that
    distance (in quadrature)."""
    p = ((cal.get('past_onset') or {}).get(fault) if onset else None) or (
        cal.get('past') or {}).get(fault)
    x = past_by(fault, g)
    if p is None or x <= 0:
        return 0.0, c
    return p['slope'] * x, dict(c, sigma=math.hypot(c['sigma'], p['rate'] * x))


def sensor_warnings(sensors: Any, control_period: float) -> list[str]:
    """What a run's recorded sensors (:class:`..physics.sensors.Sensors`, a bag's provenance)
    put outside this calibration's domain -- noise beyond 2 x :data:`NOISE` on a compared
    signal, a drift (a sensor fault the hypotheses do not include: it reads as an actuator's;
    a bias is applied by the fit, :class:`.fitting.Problem`), a quantisation step above the
    documented noise, a sample period longer than the control period -- one warning line
    each."""
    from ..physics.signals import MEASURED
    out = []
    for name, spec in (sensors.specs if sensors else ()):
        if name not in MEASURED:
            continue
        ratio = spec.noise / NOISE[name]
        if ratio > 2.0:
            out.append(f'the {name} sensor\'s noise is {ratio:.3g} x the documented level; the '
                       'intervals and the goodness of fit are calibrated for 0.5-2 x')
        # (a recorded bias is applied: the model's runs read with it)
        if spec.drift:
            out.append(f'the {name} sensor drifts: a sensor fault, which no hypothesis '
                       'includes, reads as a fault of the actuator')
        if spec.quantisation > NOISE[name]:
            out.append(f'the {name} sensor is quantised in steps of {spec.quantisation:g}, '
                       f'coarser than the documented noise ({NOISE[name]:g})')
        if spec.period is not None and spec.period > control_period * (1 + 1e-9):
            out.append(f'the {name} sensor samples every {spec.period:g} s, slower than the '
                       f'control period ({control_period:g} s): the fit compares held readings')
    return out


#: the pooled groups (Mondrian conformal groups over many flights): every answer's from the
#: start, and every answer refitted at an onset (``by_scenario['onset']``)
POOLED = 'faults'


def groups_of(scenario: str | None) -> list[str]:
    """The ONE fallback order of calibration groups for an answer on ``scenario`` (a
    calibration scenario's name, ``own`` for a flight's own, ``onset:<scenario>`` or
    ``onset`` for an answer refitted at an onset, None for none): the flight's own group, then
    the pooled group of its kind, then the pooled group from the start -- an onset answer of a
    fault no onset unit calibrated takes the from-start spread (with a warning), never the
    noise's alone."""
    from .rules import ONSET_ENTRY
    s = scenario or ''
    chain = [s] if s and s != ONSET_ENTRY else []
    if s.startswith(ONSET_ENTRY):
        chain.append(ONSET_ENTRY)
    return chain + [POOLED]


def resolve_entry(cal: Mapping[str, Any], fault: str, scenario: str | None = None
                  ) -> tuple[dict[str, Any] | None, str | None]:
    """A fault's calibration entry and the group it came from, the first of
    :func:`groups_of` that has one; a flight's own entry (not a pooled one) takes the larger
    of its own and the next group's spread unless it stands on :data:`OWN_UNITS` units.
    (None, None) for a fault no group calibrates."""
    from .rules import ONSET_ENTRY
    by = cal.get('by_scenario') or {}
    found = [(g, e) for g in groups_of(scenario)
             if (e := (cal.get(POOLED) or {} if g == POOLED else by.get(g, {})).get(fault))
             is not None]
    if not found:
        return None, None
    group, own = found[0]
    # ``scored``: the units the spread's conformal quantile stands on
    if group in (POOLED, ONSET_ENTRY) or len(found) == 1 or own['units'] >= OWN_UNITS:
        return dict(own, scored=own.get('pinned', own['units'])), group
    # a spread from the nine units of one scenario is itself uncertain (a first-stage flow
    # loss on the built-in test held 7 of 12 new units with it, 12 of 12 with the pooled one:
    # measured)
    pooled = found[1][1]
    return dict(own, sigma=max(own['sigma'], pooled['sigma']),
                k=max(own.get('k', 1.0), pooled.get('k', 1.0)),
                scored=max(own.get('pinned', own['units']),
                           pooled.get('pinned', pooled['units']))), group


def fault_calibration(cal: Mapping[str, Any], fault: str, scenario: str | None = None
                      ) -> dict[str, Any] | None:
    """A fault's calibration entry (:func:`resolve_entry`); None for a fault it lacks."""
    return resolve_entry(cal, fault, scenario)[0]


def alpha_of(cal: Mapping[str, Any] | None) -> float:
    """The miscoverage a calibration was fitted for (:data:`.conformal.ALPHA` where it does
    not say: those built before it did were all fitted at 0.1)."""
    return float((cal or {}).get('alpha', ALPHA))


def bias_at(c: Mapping[str, Any], g: float) -> float:
    """The calibrated bias of an estimate at ``g`` (its fault's coordinate)."""
    if c.get('points'):
        return float(_kernel(np.asarray(c['points']), g, c['bandwidth']))
    return c['bias'] + c.get('slope', 0.0) * (g - c.get('g0', 0.0))


def spread_of(c: Mapping[str, Any], se: float) -> float:
    """The standard deviation in ``g`` of an estimate whose fit's own is ``se``: that and the
    model-form spread, the fit's own widened by ``k`` where it does not pin the severity."""
    return math.hypot(se * (c.get('k', 1.0) if se > SE_PINNED else 1.0), c['sigma'])


@functools.lru_cache(maxsize=None)
def load_calibration(path: str | None = None) -> dict[str, Any]:
    """The packaged calibration ({} when absent), keyed by ``'<model>/<free>'``."""
    p = Path(path) if path else CALIBRATION_FILE
    if not p.is_file():
        return {}
    return json.loads(p.read_text(encoding='utf-8'))


def calibration_for(model: str, free: Sequence[str]) -> dict[str, Any] | None:
    return load_calibration().get(f'{model}/{",".join(sorted(free))}')


def onset_widen(cal: Mapping[str, Any] | None, entry: str) -> float:
    """The factor on the likelihood-ratio width of an onset's interval for calibration entry
    ``entry`` (:func:`.diagnosis.onset_entry`); 1 without a calibration."""
    return float(((cal or {}).get('onset_widen') or {}).get(entry, 1.0))


def gof_reference(cal: Mapping[str, Any], past: bool = False) -> list[float]:
    """The RMS of the right hypotheses' fits of the calibration set, sorted: those up to the
    alarm value, or (``past``: the answer lies past its fault's alarm value) those past it
    too, where the calibration has them."""
    return cal.get('past_rms') or cal['rms'] if past else cal['rms']


def gof_p_value(cal: Mapping[str, Any], rms: float, past: bool = False) -> float:
    """The share of right-hypothesis fits of the calibration set (:func:`gof_reference`) that
    fitted as badly or worse (with the plus-one rule: never 0)."""
    return p_value(gof_reference(cal, past), rms)


__all__ = ['alpha_of', 'onset_widen', 'fit_calibration', 'gof_reference', 'past_correction',
           'fault_calibration', 'resolve_entry', 'groups_of', 'POOLED', 'bias_at',
           'sensor_warnings', 'spread_of', 'load_calibration', 'calibration_for', 'gof_p_value',
           'SCENARIO_UNITS', 'CALIBRATION_FILE']
