"""The model-form term of a diagnosis: what the simplified model's own error against HD does
to an answer, from a calibration (the packaged one, or the flight's own:
:mod:`.flight_calibration`) -- the goodness-of-fit test that makes a run ``unexplained``, the
bias correction and the model-form spread of the verdict's severity, and the size a verdict
states (:func:`reported_severity`), which the verdict floor and the detection limits are in.
The procedure and what was measured: doc/explanation/diagnosis.md."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS
from ..physics.simulate import simulate
from .calibration import (POOLED, alpha_of, bias_at, fault_calibration, gof_p_value, gof_reference,
                          past_correction, resolve_entry, spread_of)
from .calibration_set import from_g, past_by, to_g
from .conformal import enough, units_needed, z_of
from .fitting import SIGNALS, Problem
from .rules import ONSET_ENTRY
from .verdict import HEALTHY, UNEXPLAINED, Diagnosis

#: no hypothesis explains a run whose best fit's RMS exceeds UNEXPLAINED_FACTOR times the
#: REFERENCE_QUANTILE of the right hypotheses' fits in the calibration set (the quantile, not
#: the maximum: a few fits of the set itself stop in a wrong valley)
REFERENCE_QUANTILE = 0.98
UNEXPLAINED_FACTOR = 1.5

def apply_model_form(d: Diagnosis, cal: Mapping[str, Any] | None, free: Sequence[str],
                     scenario: str | None, problem: Problem) -> None:
    """The calibration ``cal`` (of the model with ``free`` nuisance; None: none packaged):
    its bias correction and model-form spread on the verdict, and the goodness-of-fit test
    (see :mod:`.calibration`).

    The test's limit is the larger of two: the calibration set's (right hypotheses on the
    calibration flights) and :data:`UNEXPLAINED_FACTOR` times the model's own misfit on this
    flight (:func:`flight_model_form_rms`). A flight beyond the calibration's -- a 2-30 Hz chirp,
    where SQ's nominal run is 5.4 residual scales from HD's against 0.8-1 on the calibration
    flights -- made every healthy unit 'unexplained' though no fault improved on healthy: the
    misfit was the model's, which this flight shows as it shows any fault's."""
    if cal is None:
        d.warnings.append(f'no model-form calibration for {d.model} with free '
                          f'{",".join(sorted(free)) or "none"}: the interval counts the '
                          'measurement noise only')
        return
    d.calibration = cal
    d.calibration_scenario = scenario if scenario in (cal.get('by_scenario') or {}) else None
    if _explained(d, cal, problem):
        _correct(d, cal, scenario)


def _explained(d: Diagnosis, cal: Mapping[str, Any], problem: Problem) -> bool:
    """The goodness-of-fit test (:func:`apply_model_form`): False, the verdict made
    ``unexplained`` with a warning, where the best fit's RMS is beyond the limit."""
    # an answer past its fault's alarm value is tested against every right fit, those past
    # it included (they fit worse)
    past = len(d.best.faults) == 1 and past_by(d.best.fault,
                                               to_g(d.best.fault, d.best.severity)) > 0
    d.p_value = gof_p_value(cal, d.fit_rms, past)
    d.fit_limit = UNEXPLAINED_FACTOR * float(np.quantile(gof_reference(cal, past),
                                                         REFERENCE_QUANTILE))
    d.flight_model_form_rms = flight_model_form_rms(problem)
    own = UNEXPLAINED_FACTOR * (d.flight_model_form_rms or 0.0)
    if own > d.fit_limit:
        d.fit_limit = own
        d.warnings.append(f'{d.model} follows HD on this flight to RMS '
                          f'{d.flight_model_form_rms:.3g} of the residual scales, beyond the '
                          'calibration flights\' mismatch: a fit is unexplained only beyond '
                          f'{own:.3g} here, and the calibrated intervals may be too narrow')
    if d.fit_rms > d.fit_limit:
        d.verdict = UNEXPLAINED
        d.warnings.append(f'no hypothesis explains the run: the best ({d.best.fault}) fits with '
                          f'RMS {d.fit_rms:.3g} of the residual scales, beyond {d.fit_limit:.3g} '
                          f'({UNEXPLAINED_FACTOR:g} x the {REFERENCE_QUANTILE:.0%} quantile of '
                          f'right hypotheses in the calibration set, or of the model\'s own '
                          f'misfit on this flight; p = {d.p_value:.2g})')
        return False
    return True


def _correct(d: Diagnosis, cal: Mapping[str, Any], scenario: str | None) -> None:
    """The calibration's bias correction and model-form spread on an explained verdict, and
    the warnings where its guarantee does not reach; a healthy verdict says which faults the
    flight does not reveal."""
    best = d.best
    if best.fault == HEALTHY:
        hidden = [f for f, s in (cal.get('revealed_from') or {}).items() if s is None]
        if hidden:
            # healthy means "no fault this flight reveals": say which it does not
            d.warnings.append('this flight does not reveal ' + ', '.join(hidden) + ' (its '
                              'calibration units at the alarm value were not all named): '
                              'fly the built-in test (servovalve-twin bit --out bit.yaml) '
                              'to see them')
        return
    best.raw = (best.severity, best.interval)
    sevs, ivs = [], []
    alpha = alpha_of(cal)
    for f, s, iv in zip(best.faults, best.severities, best.intervals):
        c, group = resolve_entry(cal, f, scenario)
        if c is None:
            # never a noise-only interval stated as calibrated without a word
            d.warnings.append(f'the model-form calibration has no entry for {f} (too few of '
                              'its units were named): its interval counts the measurement '
                              'noise only and may be too narrow')
        elif group == POOLED and (scenario or '').startswith(ONSET_ENTRY):
            d.warnings.append(f'no onset unit of {f} in the calibration: the interval takes '
                              'the spread of answers fitted from the start, which an onset\'s '
                              'may exceed')
        if c is not None and not enough(c['scored'], alpha):
            d.warnings.append(f'the calibration of {f} stands on {c["scored"]} units, fewer '
                              f'than the {units_needed(alpha)} a {1 - alpha:.0%} conformal '
                              'bound needs: its interval is the widest they ask, not '
                              'guaranteed')
        s, iv, _ = model_form_estimate(cal, f, s, iv, scenario)
        sevs.append(s)
        ivs.append(iv)
    best.severity = sevs[0] if len(sevs) == 1 else sevs
    best.interval = ivs[0] if len(ivs) == 1 else ivs
    d.confidence = 1.0 - alpha
    # a calibration whose units fly severities up to each fault's alarm value only (one
    # built before it flew units past it, or a fault it has too few of there): an interval
    # wholly past it is extrapolated (at 1.15 of the way, 12 of 18 onset answers' intervals
    # held the truth: measured)
    for f, iv in zip(best.faults, ivs):
        if min(past_by(f, to_g(f, s)) for s in iv) <= 0:
            continue
        past = (cal.get('past') or {}).get(f)
        if past is None:
            d.warnings.append(f'{f} past its alarm value ({FAULTS[f].demo:g}): the model-form '
                              'calibration flies severities up to it, so this answer is '
                              'extrapolated and its interval may be too narrow')
        elif not enough(past.get('scored', past['units']), alpha):
            d.warnings.append(f'{f} past its alarm value: the calibration\'s growth of the '
                              f'spread there stands on {past.get("scored", past["units"])} '
                              f'units, fewer than the {units_needed(alpha)} a '
                              f'{1 - alpha:.0%} conformal bound needs: not guaranteed')
    d.interval_counts = 'measurement noise and the model-form error calibrated against HD' + (
        ' for a fault that began mid-flight' if (d.calibration_scenario or '').startswith(
            ONSET_ENTRY) else
        f' on this flight ({d.calibration_scenario})' if d.calibration_scenario else '')



def flight_model_form_rms(problem: Problem) -> float | None:
    """The fitted model's own misfit on the recorded flight: the RMS, in residual scales, of
    its run at the design parameters against HD's at the same parameters, both on the
    recorded inputs over the window (one HD run: ~9 ms per second of flight). None where HD
    does not converge on those inputs."""
    try:
        hd = simulate('HD', problem.scenario, params=problem.design,
                      ecu_period=problem.control_period, initial=problem.initial)
    except TwinError:
        return None
    own = problem.run(problem.params((), [], {}))
    if own is None:
        return None
    r = problem.residuals(own, {s: hd[s][problem.model_rows] for s in SIGNALS})
    return float(np.sqrt(np.mean(r * r)))



#: a fit within this fraction of the catalog's range of its end is at the end (censored)
CENSORED = 1e-6



def model_form_estimate(cal: Mapping[str, Any], fault: str, severity: float,
                        interval95: tuple[float, float], scenario: str | None = None
                        ) -> tuple[float, tuple[float, float], float]:
    """A fault's severity less the calibrated bias, its 90 % interval with the model-form
    spread (the fit's 95 % interval read as a standard error), and that spread as a relative
    standard deviation of the distance from healthy (what :func:`..prognosis.prognose` takes
    as ``model_sigma``). Unchanged, with a spread of 0, for a fault the calibration lacks.
    ``scenario``: the calibration scenario the flight is (its own entry, where there is one).
    A fit past the fault's alarm value is corrected further, and its spread widened, by the
    calibration's units past it (:func:`.calibration.past_correction`)."""
    spec = FAULTS[fault]
    c = fault_calibration(cal, fault, scenario)
    lo, hi = interval95
    if c is None:
        return severity, (lo, hi), 0.0
    se = (to_g(fault, hi) - to_g(fault, lo)) / (2 * 1.96)
    g = to_g(fault, severity)
    further, c = past_correction(cal, fault, g, c, (scenario or '').startswith(ONSET_ENTRY))
    g = g - bias_at(c, g) - further
    half = z_of(alpha_of(cal)) * spread_of(c, se)
    est = min(max(from_g(fault, g), spec.lo), spec.hi)
    iv = (min(max(from_g(fault, g - half), spec.lo), spec.hi),
          max(min(from_g(fault, g + half), spec.hi), spec.lo))
    # a fit stopped at an end of the catalog's range (not healthy's) is censored there:
    # unbounded it would read beyond, so the truth may lie anywhere up to that end (a null
    # bias at its alarm value, -5 mA, the catalog's end, from 0.6 s on the built-in test:
    # fitted at -5.000 mA, corrected to -4.91 with a spread of +-0.01 that missed the truth:
    # measured); so is one whose own interval runs to that end, the one-sided answer
    # (``bounds``: a static friction of 20 x fitted 16.5 x, flat from 8.3 x to 50 x, was
    # answered ">= 8.3" with a corrected interval ending at 28)
    tol = CENSORED * (spec.hi - spec.lo)
    for end in (spec.lo, spec.hi):
        if end != spec.healthy and min(abs(v - end) for v in (severity, lo, hi)) <= tol:
            iv = (min(iv[0], end), max(iv[1], end))
    # the spread in g as a relative error of s - h: dg * s/(s - h) for a multiplier (g = ln
    # s/h), dg * span/|s - h| for a fraction or value; capped where s is near healthy
    dist = max(abs(est - spec.healthy), 0.05 * abs(spec.demo - spec.healthy))
    rel = c['sigma'] * (est if spec.kind == 'scale' else abs(spec.demo - spec.healthy)) / dist
    return est, iv, float(min(rel, 0.5))



def reported_severity(cal: Mapping[str, Any] | None, fault: str, severity: float,
                      scenario: str | None) -> float:
    """The severity a verdict states for a fit of ``severity``: less the calibrated bias of
    ``fault`` (the scenario's own entry where there is one), kept within the catalog's range
    (:func:`model_form_estimate`'s); unchanged without a calibration of the fault. The verdict
    floor of a flight's calibration and the detection limits are sizes in it, so that a fault
    is named only where its stated size clears them (two healthy units of a sine flight were
    named a gain loss fitted above the floor but stated at 0.0: measured)."""
    if cal is None:
        return severity
    return model_form_estimate(cal, fault, severity, (severity, severity), scenario)[0]


__all__ = ['apply_model_form', 'model_form_estimate', 'reported_severity',
           'flight_model_form_rms', 'REFERENCE_QUANTILE', 'UNEXPLAINED_FACTOR', 'CENSORED']
