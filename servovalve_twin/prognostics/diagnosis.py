"""Diagnosis from a recorded run: which catalog fault, how severe, with what confidence.

Parameter estimation on a fast model, after Dalla Vedova, Maggiore and Pace (WSEAS 2014): a
simplified model of the whole actuator (default SQ), driven by the run's recorded Com, FR and
PSR through the same compiled physics as ``simulate`` (ECU sampled at the run's control
period), is fitted to the recorded XJ, DXJ and P12 once per hypothesis -- healthy, and each
catalog fault (:data:`~..physics.faults.FAULTS`) with its severity free within the catalog's
bounds, and with ``pairs`` each two faults at once -- by bounded nonlinear least squares
(``scipy.optimize.least_squares``). Nuisance parameters the user names (``free``: M, CJ, ...)
are estimated alongside, as factors on their design values in [0.5, 2].

Residuals. Each signal's residual is divided by a scale of what the model cannot follow
(:data:`RESIDUAL_SCALE`: about the SQ model's RMS error against HD on the paper scenario), so
that XJ, DXJ and P12 weigh alike.

Ranking. The hypotheses are ranked by the Bayesian information criterion of their residuals,
``n_eff*ln(RSS/n) + k*ln(n_eff)``, with ``k`` the fitted parameters and ``n_eff`` the effective
number of independent residuals -- model-mismatch residuals are strongly autocorrelated, so
``n_eff = n*(1 - rho)/(1 + rho)`` with ``rho`` their lag-1 autocorrelation under the healthy
hypothesis (an AR(1) reading); with ``n`` the criterion would call a fault on every healthy
unit, each fault absorbing a little of the mismatch.

Verdict. The best-ranked hypothesis, except that a fault fitted at less than
:data:`DETECTABLE` (20 %) of the way from healthy to its catalog alarm severity, in the fault's
calibration coordinate (geometric for a multiplier: 1.58 x for leakage, whose alarm is 10 x),
is not reported over healthy: that small a fit is the model's mismatch and the nuisance (24
healthy HD units, nuisance at 1.5 x the documented spread, M and CJ free, three scenarios: at
most 0.15 of the way for every fault whose likelihood is not flat). The detection limits this
sets, with those of the excitation, are :mod:`.excitation`'s. A pair is reported only when
both its faults are that large, and when its score is :data:`PAIR_EVIDENCE` (10) below each of
its two single faults' -- a second fault absorbs some of SQ's mismatch against HD and wins by
1-7 points on units with one fault (measured), where units with two faults give 57-136.
``candidates`` keep every fit, in score order after the verdict.

Confidence. A severity's 95 % interval comes from the fit's Jacobian, ``cov = s^2
(J^T J)^-1`` inflated by ``n/n_eff`` for the correlation -- ``n_eff`` here from the
hypothesis' own residuals: about ``n`` for a fit that leaves only white noise, so that the
interval is then the spread of repeated flights (tested) -- or the catalog's bounds where the
residuals do not move with the severity at the fit. The verdict's is joined with the
likelihood-ratio interval along its severity (:func:`.fitting.ratio_interval`): a fit that
stops on a flat stretch of the cost -- static friction beyond the break-away the run reaches --
has a zero Jacobian there and a Jacobian interval of zero width. With ``bootstrap`` = N, the
verdict's interval is instead from N refits to the fitted signals plus moving blocks (50 ms)
of the residuals (percentiles).

Pairs. A pair is named ``'a+b'`` (catalog order) and its ``severity`` and ``interval`` are
lists, one entry per fault in that order. Its fit starts from the best of the two single-fault
optima and a :data:`PAIR_GRID` x :data:`PAIR_GRID` grid of both severities. Without
``pairs``, a single-fault verdict is still paired with each other fault, started from the two
singles' optima (:func:`_second_fault`): two faults of at least the mild size that fit far
better than the verdict make the run ``unexplained`` -- outside the single-fault hypotheses,
never a confident single name -- with the pair listed second among the candidates.

The hypothesis holds over the whole simulated stretch, from t = 0 to the window's end: a flight
with one degradation level (prognosis). A fault that appears mid-run is diagnosed on a window
after its onset, with the model run faulty from the start -- a bias for faults that change the
state before the window -- unless ``start`` (after the onset) has the model start from the
recorded jack state there, as the live estimator does; ``onset`` fits the instant it began
(:func:`.onset.fit_onset`). What the answer's confidence counts -- the model-form calibration, the
goodness of fit, identifiability -- is doc/explanation/diagnosis.md.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS
from ..physics.params import PARAM_NAMES, EhaParams
from .conformal import enough, units_needed, z_of
from .fitting import (FREEABLE_BIAS, SIGNALS, Problem, bootstrap_intervals, effective_n, fit,
                      free_interval, free_start, jacobian_interval, ratio_interval, start_grid)
from .rules import (DETECTABLE, DIAGNOSABLE, ONSET_ENTRY, PAIR_EVIDENCE, above_floor,
                    onset_entry, sized)
from .verdict import HEALTHY, UNEXPLAINED, Candidate, Diagnosis

#: no hypothesis explains a run whose best fit's RMS exceeds UNEXPLAINED_FACTOR times the
#: REFERENCE_QUANTILE of the right hypotheses' fits in the calibration set (the quantile, not
#: the maximum: a few fits of the set itself stop in a wrong valley)
REFERENCE_QUANTILE = 0.98
UNEXPLAINED_FACTOR = 1.5
#: severities per fault of a pair's start grid
PAIR_GRID = 5
#: without --pairs, a pair of the verdict's fault and another that beats the verdict by
#: SECOND_FAULT_EVIDENCE makes the run `unexplained` (a second fault absorbs some of SQ's
#: mismatch against HD and wins by up to 40 on units with one fault, its second fault fitted
#: near the detection floor; units with two faults at 0.8 of the way to their alarm values
#: give 57-136: measured), when both faults are at least SECOND_FAULT_SIZE (the mild level) of
#: the way to their alarm values. Every other fault is screened: a second fault's own single
#: fit may rank last (a leak beside a supply loss, on a flight with little load)
SECOND_FAULT_EVIDENCE = 20.0
SECOND_FAULT_SIZE = 0.3


def diagnose(signals: Mapping[str, np.ndarray], design: EhaParams, *, control_period: float,
             model: str = 'SQ', faults: Sequence[str] = DIAGNOSABLE,
             window: tuple[float, float] | None = None, free: Sequence[str] = (),
             bootstrap: int = 0, seed: int = 0, pairs: bool = False,
             start: float | None = None, model_form: bool = True,
             onset: bool = False, scenario: str | None = None,
             from_rest: bool = True, calibration: Mapping[str, Any] | None = None,
             sensor_bias: Mapping[str, float] | None = None) -> Diagnosis:
    """Fit every hypothesis and rank them (see the module docstring).

    :param signals: the run's 1 ms rows (``read_bag(...).signals``, ``simulate(...).signals``)
    :param design: the parameters the run was meant to have (a bag's provenance)
    :param control_period: the ECU's sampling period of the run [s]
    :param pairs: also fit every two of ``faults`` at once
    :param start: run the model from this instant [s] (at most the window's start), from the
        recorded XJ and DXJ there, instead of from t = 0: the cost of a fit is then that of
        ``window end - start`` whatever the run's length (the live estimator's warm-up)
    :param model_form: the recorded actuator is not the fitted model (a real one, or HD):
        correct the verdict's severity for the model's calibrated bias, widen its interval by
        the calibrated model-form spread (a 90 % interval) and test the goodness of fit
        (:mod:`.calibration`); False when the run is the fitted model's own (the model is
        exact) or to calibrate
    :param onset: also fit when a single-fault verdict began (see :func:`.onset.fit_onset`)
    :param from_rest: the first row is the run's start, from rest (a bag of a whole flight):
        a fit from there starts at rest, not at the first (noisy) recorded XJ and DXJ; False
        when the rows begin mid-run (the live estimator's kept rows)
    :param scenario: the calibration scenario the run flew (``'bit'``, ``'paper'``), whose own
        model-form calibration then applies (:func:`.calibration.fault_calibration`); a bag's
        is found by :func:`..apps.diagnose.calibration_scenario`
    :param calibration: the model-form calibration to apply instead of the packaged one: the
        flight's own (:mod:`.flight_calibration`, with ``scenario`` its ``'own'`` entry), whose
        healthy units also set the verdict floor
    :param sensor_bias: the sensors' known offsets by signal (``{'xj': 5e-5}``: a bag's
        recorded sensor model), which the model's runs then read with; an unknown one is
        freed instead (``free``: ``xj_bias``, ``dxj_bias``, ``p12_bias``)
    """
    faults = _hypotheses(faults, free, pairs)
    free = list(free)
    problem = Problem(signals, design, model, control_period, window, start, from_rest,
                      sensor_bias)
    results, singles = _fit_hypotheses(problem, faults, free, pairs)
    n = len(results[0][2])
    n_eff = effective_n(results[0][2], len(SIGNALS))
    candidates = [_candidate(problem, *r, free, n, n_eff) for r in results]
    candidates.sort(key=lambda c: c.score)
    # the verdict: the best-scoring hypothesis, healthy where that is a fault below a size
    # worth reporting (DETECTABLE of its alarm severity: the model's own mismatch -- a healthy
    # HD unit fits a 2 % null bias under SQ -- or a fault below what the flight can show).
    # It never hands the run to the next hypothesis: on a flight where SQ's mismatch looked
    # like a small gain loss (0.053, below its floor), the walk down the ranking named the
    # next fault above its own floor (a supply loss of 0.073) in every healthy unit. The size is
    # the model-form-corrected one, the severity the answer would state and the detection
    # limits are in: SQ reads a leak on the paper flight ~10 % low, and a 1.7 x leak (limit
    # 1.585 x), fitted at 1.45-1.54, was called healthy (measured)
    from .calibration import calibration_for, onset_widen
    if calibration is not None:
        cal = calibration if model_form else None
    else:
        cal = calibration_for(model, free) if model_form else None
    by_name = {c.fault: c for c in candidates}
    best = _verdict_candidate(candidates, by_name, cal, scenario)
    candidates.remove(best)
    candidates.insert(0, best)
    second = None
    if not pairs and not onset and len(best.faults) == 1 and len(faults) > 1:
        second = _second_fault(problem, best, singles, candidates, free, n, n_eff)
        if second is not None:
            candidates.insert(1, second)
    if best.fault != HEALTHY:
        hyp, x, res, jac = next(r for r in results if '+'.join(r[0]) == best.fault)
        n_own = effective_n(res, len(SIGNALS))
        ivs = [ratio_interval(problem, hyp, i, x, free, res, n, n_own, jac)
               for i in range(len(hyp))]
        best.interval = ivs[0] if len(ivs) == 1 else ivs
        bounds = [_one_sided(f, iv) for f, iv in zip(hyp, ivs)]
    else:
        bounds = []
    from .onset import fit_onset
    # an answer refitted at an onset has an error of its own (the fault seen over part of the
    # window, its instant estimated): the calibration's onset units on this flight (else on
    # every onset flight) set its correction, its spread and how wide against the noise's
    # alone the onset's interval is
    entry = onset_entry(cal, scenario)
    # the single faults the run cannot tell from the verdict: within PAIR_EVIDENCE of it in
    # the information criterion, from the start or (``onset``) from an onset of their own
    rivals = [] if best.fault == HEALTHY or len(best.faults) > 1 else [
        c.fault for c in candidates[1:] if len(c.faults) == 1
        and c.score - best.score < PAIR_EVIDENCE and _detectable(c, cal=cal, scenario=scenario)]
    onset_fit = fit_onset(problem, candidates, n, n_eff,
                          lambda f, s: reported_severity(cal, f, s, entry),
                          widen=onset_widen(cal, entry), rivals=rivals) if onset else None
    onset_profile = onset_fit.pop('profile', None) if onset_fit else None
    # a fault that may have begun any time up to the onset interval's end: its severity is
    # what fits from the start or from that late (:func:`.onset.severity_range`), and where
    # that reaches the catalog's end the answer is a one-sided bound
    late_range = onset_fit.pop('severity_range', None) if onset_fit else None
    if onset_fit is not None:
        # (the factor is set for 1 - alpha of the calibration's onset units; without it
        # the interval is the noise's 95 % likelihood-ratio one)
        from .calibration import alpha_of
        onset_fit['confidence'] = 1.0 - alpha_of(cal) if cal is not None else 0.95
    # an onset refitted the verdict at it (not when the fit from the start stands and only
    # when the fault began is in doubt)
    refitted = onset_fit is not None and not onset_fit.get('from_start')
    if refitted:
        best, bounds = candidates[0], ['']
    # (the bootstrap refits faults present from the start: not an onset's)
    if bootstrap and best.fault != HEALTHY and not refitted:
        boot = bootstrap_intervals(problem, best, free, bootstrap, seed)
        best.interval = boot[0] if len(boot) == 1 else boot
    if late_range is not None:
        best.interval = (min(best.interval[0], late_range[0]),
                         max(best.interval[1], late_range[1]))
        bounds = [_one_sided(best.fault, best.interval)]
    d = Diagnosis(model=model, window=problem.window, candidates=candidates, n_eff=n_eff,
                  evaluations=problem.evaluations, recorded=dict(problem.recorded, t=problem.t),
                  fit_rms=math.sqrt(best.rss / n), bounds=bounds, onset=onset_fit,
                  onset_profile=onset_profile,
                  rivals=sorted(set(rivals) - {best.fault}))
    if second is not None:
        d.verdict = UNEXPLAINED
        d.warnings.append(f'unexplained: two faults at once ({second.fault}) fit better than '
                          f'{best.fault} alone by {best.score - second.score:.0f} in the '
                          f'information criterion (more than {SECOND_FAULT_EVIDENCE:g}): '
                          'outside the single-fault hypotheses; diagnose with --pairs')
    if onset_fit is not None and not onset_fit['identifiable']:
        lo, hi = onset_fit['interval']
        d.warnings.append(f'onset not identifiable on this run: {onset_fit["fault"]} began '
                          f'between {lo:.3f} and {hi:.3f} s (the fit does not change within '
                          'it: the flight did not excite the fault there)')
    if any(bounds):
        d.warnings.append('not identifiable on this run: ' + '; '.join(b for b in bounds if b)
                          + ' (the fit does not change beyond it: only a flight that excites '
                          'it more can pin it)')
    if model_form:
        _apply_model_form(d, cal, free, entry if refitted else scenario, problem)
    return d


def _hypotheses(faults: Sequence[str], free: Sequence[str], pairs: bool) -> list[str]:
    """The faults to hypothesise, checked, in catalog order (so that a pair has one name
    whatever order the user gave)."""
    for f in faults:
        if f not in FAULTS:
            raise TwinError(f'unknown fault {f!r}; expected one of {list(DIAGNOSABLE)}')
        if f not in DIAGNOSABLE:
            raise TwinError(f'fault {f!r} acts on HD geometry a simplified model does not '
                            f'have; expected one of {list(DIAGNOSABLE)}')
    for p in free:
        if p == 'xj_bias':
            raise TwinError('--free xj_bias: an offset of the XJ sensor cannot be estimated '
                            'from the run (the loop drives the reading, not the jack, to the '
                            'command); a known one is applied from the bag\'s sensors: '
                            f'section. Freeable offsets: {", ".join(FREEABLE_BIAS)}')
        if p not in PARAM_NAMES and p not in FREEABLE_BIAS:
            raise TwinError(f'--free: unknown parameter {p!r} (a model parameter, or a '
                            f'sensor offset: {", ".join(FREEABLE_BIAS)})')
    if any(FAULTS[f].param in free for f in faults):
        raise TwinError('--free names a parameter a fault hypothesis estimates')
    faults = [f for f in DIAGNOSABLE if f in set(faults)]
    if pairs and len(faults) < 2:
        raise TwinError('--pairs needs at least two faults to pair')
    return faults


def _fit_hypotheses(problem: Problem, faults: Sequence[str], free: list[str], pairs: bool):
    """Healthy, each single fault and (``pairs``) each two: ``[(hypothesis, x, residuals,
    jacobian), ...]`` and each single fault's optimum."""
    results = [((), *fit(problem, (), free))]
    singles = {}
    for fault in faults:
        x, res, jac = fit(problem, (fault,), free)
        singles[fault] = x
        results.append(((fault,), x, res, jac))
    if pairs:
        for i, a in enumerate(faults):
            for b in faults[i + 1:]:
                # the best of a coarse grid over both severities and of the two singles'
                # optima: a fault near healthy has a flat gradient, and one fault can take on
                # much of the other's effect, so a fit started from the singles alone stays in
                # the wrong valley (leakage beside a supply loss does)
                xa, xb = singles[a], singles[b]
                nuis = list((xa[1:] + xb[1:]) / 2)
                starts = [[xa[0], xb[0]] + nuis] + [
                    [ga, gb] + [free_start(k) for k in free]
                    for ga in start_grid(a, PAIR_GRID) for gb in start_grid(b, PAIR_GRID)]
                results.append(((a, b), *fit(problem, (a, b), free, starts=starts)))
    return results, singles


def _candidate(problem: Problem, hyp: tuple[str, ...], x: np.ndarray, res: np.ndarray,
               jac: np.ndarray, free: Sequence[str], n: int, n_eff: float) -> Candidate:
    """A fitted hypothesis as a candidate: its score, severities, Jacobian intervals."""
    rss = float(np.dot(res, res))
    score = n_eff * math.log(max(rss, 1e-300) / n) + len(x) * math.log(n_eff)
    sevs = [float(v) for v in x[:len(hyp)]]
    # the interval's correlation is that of the hypothesis' own residuals: white where the
    # model fits but for noise, strongly correlated where it cannot follow
    n_own = effective_n(res, len(SIGNALS))
    intervals = [jacobian_interval(f, i, x, res, jac, n, n_own) or (FAULTS[f].lo, FAULTS[f].hi)
                 for i, f in enumerate(hyp)]
    freev = dict(zip(free, x[len(hyp):].tolist()))
    free_ivs = {k: iv for j, k in enumerate(free)
                if (iv := free_interval(k, len(hyp) + j, x, res, jac, n, n_own)) is not None}
    fitted = problem.run(problem.params(hyp, sevs, freev))
    if len(hyp) == 1:
        sev, interval = sevs[0], intervals[0]
    elif hyp:
        sev, interval = sevs, intervals
    else:
        sev = interval = None
    return Candidate('+'.join(hyp) or HEALTHY, sev, interval, score, rss, freev, fitted or {},
                     free_intervals=free_ivs)


def _second_fault(problem: Problem, best: Candidate, singles: Mapping[str, np.ndarray],
                  candidates: Sequence[Candidate], free: Sequence[str], n: int, n_eff: float
                  ) -> Candidate | None:
    """Without ``pairs``: is a single-fault verdict really two faults? Screened first, one
    model run per other fault: the verdict's fit with that fault added at its mild severity
    gives a secant ``d_b`` of its effect (a secant, not a derivative: static friction has none
    at healthy), a step of the verdict's own severity gives ``d_a``, and the residual's
    least-squares projection on both the RSS a pair could gain (the verdict's severity moves
    too: a single fault has taken on part of the other's effect). The screen is linear and
    underestimates a large second fault (a 5.7 x leak beside a supply loss: 2 points where the
    fit gains 77), so any fault that would pay for its parameter at all passes it and is then
    fitted as a pair with the verdict's, started from the two singles' optima; the best pair,
    if it beats the verdict by :data:`SECOND_FAULT_EVIDENCE` with both faults of at least the
    mild size, else None."""
    from .calibration import from_g, severity_at, to_g
    a = best.faults[0]
    spec = FAULTS[a]
    r = problem.residuals(best.fitted or None)
    rss = float(r @ r)
    # a step of a twentieth of the way to the alarm value, inward if outward leaves the range
    g = to_g(a, best.severities[0])
    step = 0.05 * to_g(a, spec.demo)
    s_a = from_g(a, g + step)
    if not spec.lo <= s_a <= spec.hi:
        s_a = from_g(a, g - step)
    d_a = problem.residuals(problem.run(problem.params((a,), [s_a], best.free))) - r
    found = None
    for b in [c.faults[0] for c in candidates if len(c.faults) == 1 and c.fault != a]:
        hyp = tuple(f for f in DIAGNOSABLE if f in (a, b))          # catalog order
        sev = {a: best.severities[0], b: severity_at(b, SECOND_FAULT_SIZE)}
        moved = problem.run(problem.params(hyp, [sev[f] for f in hyp], best.free))
        basis = np.column_stack([d_a, problem.residuals(moved) - r])
        coef = np.linalg.lstsq(basis, -r, rcond=None)[0]
        gain = rss - float(np.sum((r + basis @ coef) ** 2))
        if coef[1] <= 0 or n_eff * math.log(rss / max(rss - gain, 1e-300)) < math.log(n_eff):
            continue
        xa, xb = singles[hyp[0]], singles[hyp[1]]
        start = [xa[0], xb[0]] + list((xa[1:] + xb[1:]) / 2)
        cand = _candidate(problem, hyp, *fit(problem, hyp, free, starts=[start]), free, n,
                          n_eff)
        # both faults of at least the mild size: a second fault fitted near the detection
        # floor is absorbing the model's mismatch and the nuisance, not a fault
        if best.score - cand.score >= SECOND_FAULT_EVIDENCE and _detectable(
                cand, SECOND_FAULT_SIZE) and (
                found is None or cand.score < found.score):
            found = cand
    return found


def _apply_model_form(d: Diagnosis, cal: Mapping[str, Any] | None, free: Sequence[str],
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
    from .calibration import alpha_of, gof_p_value, gof_reference, past_by, to_g
    if cal is None:
        d.warnings.append(f'no model-form calibration for {d.model} with free '
                          f'{",".join(sorted(free)) or "none"}: the interval counts the '
                          'measurement noise only')
        return
    d.calibration = cal
    d.calibration_scenario = scenario if scenario in (cal.get('by_scenario') or {}) else None
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
        return
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
    from .calibration import POOLED, resolve_entry
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
    from ..physics.simulate import simulate
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
    from .calibration import (alpha_of, bias_at, fault_calibration, from_g, past_correction,
                              spread_of, to_g)
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


def _one_sided(fault: str, interval: tuple[float, float]) -> str:
    """'' where the likelihood-ratio interval ends inside the catalog's range on the side away
    from healthy; else the one-sided bound it supports (the near end)."""
    spec = FAULTS[fault]
    lo, hi = interval
    up = spec.demo > spec.healthy
    far = hi if up else lo
    limit = spec.hi if up else spec.lo
    if abs(far - limit) > 1e-9 * max(1.0, abs(limit)):
        return ''
    near = lo if up else hi
    return f'{fault} {">=" if up else "<="} {near:.4g}'


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


def _verdict_candidate(candidates: list[Candidate], by_name: Mapping[str, Candidate],
                       cal: Mapping[str, Any] | None, scenario: str | None) -> Candidate:
    """The verdict among ``candidates`` (best score first): a pair only with both faults
    worth reporting and PAIR_EVIDENCE better than each of its singles (else the ranking goes
    on to them); the first single fault if it is worth reporting, else healthy."""
    for c in candidates:
        if c.fault == HEALTHY:
            return c
        if len(c.faults) == 2:
            if _detectable(c, cal=cal, scenario=scenario) and all(
                    by_name[f].score - c.score >= PAIR_EVIDENCE for f in c.faults):
                return c
            continue
        return c if _detectable(c, cal=cal, scenario=scenario) else by_name[HEALTHY]
    return by_name[HEALTHY]


def _detectable(c: Candidate, fraction: float = DETECTABLE,
                cal: Mapping[str, Any] | None = None, scenario: str | None = None) -> bool:
    """Every fault of ``c`` of a size worth reporting: beyond the verdict floor of the flight's
    own calibration where ``cal`` is one (:mod:`.flight_calibration`: what no healthy unit of
    this flight and design fitted), else :func:`sized` -- either on the size the verdict would
    state (:func:`reported_severity`)."""
    out = True
    for f, s in zip(c.faults, c.severities):
        size = reported_severity(cal, f, s, scenario)
        beyond = above_floor(cal, f, size) if fraction == DETECTABLE else None
        out = out and (beyond if beyond is not None else sized(f, size, fraction))
    return out


__all__ = ['diagnose', 'Diagnosis', 'Candidate', 'DIAGNOSABLE', 'HEALTHY', 'UNEXPLAINED',
           'model_form_estimate', 'reported_severity']
