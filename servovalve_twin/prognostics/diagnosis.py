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
likelihood-ratio interval along its severity (:func:`.fit_intervals.ratio_interval`): a fit that
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
from .calibration import alpha_of, calibration_for, onset_widen
from .fit_intervals import bootstrap_intervals, free_interval, jacobian_interval, ratio_interval
from .fitting import FREEABLE_BIAS, SIGNALS, Problem, effective_n, fit, free_start, start_grid
from .modelform import apply_model_form, reported_severity
from .rules import DETECTABLE, DIAGNOSABLE, PAIR_EVIDENCE, above_floor, onset_entry, sized
from .verdict import HEALTHY, UNEXPLAINED, Candidate, Diagnosis

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
             sensor_bias: Mapping[str, float] | None = None, second_fault: bool = True
             ) -> Diagnosis:
    """Fit every hypothesis and rank them (see the module docstring).

    :param signals: the run's 1 ms rows (``read_bag(...).signals``, ``simulate(...).signals``)
    :param design: the parameters the run was meant to have (a bag's provenance)
    :param control_period: the ECU's sampling period of the run [s]
    :param pairs: also fit every two of ``faults`` at once
    :param second_fault: without ``pairs``, screen a single-fault verdict for a second fault
        (:func:`_second_fault`); False where only the ranking is read (a calibration's units)
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
    candidates = sorted((_candidate(problem, *r, free, n, n_eff) for r in results),
                        key=lambda c: c.score)
    cal = (calibration if calibration is not None else calibration_for(model, free)) \
        if model_form else None
    best = _verdict_candidate(candidates, {c.fault: c for c in candidates}, cal, scenario)
    candidates.remove(best)
    candidates.insert(0, best)
    second = _second_fault(problem, best, singles, candidates, free, n, n_eff) if \
        second_fault and not (pairs or onset) and len(best.faults) == 1 and len(faults) > 1 \
        else None
    if second is not None:
        candidates.insert(1, second)
    bounds = _verdict_interval(problem, best, results, free, n)
    # an onset answer's error is its own (the fault seen over part of the window, its instant
    # estimated): the calibration's onset units on this flight (else on every onset flight)
    # set its correction, its spread and its onset interval's width against the noise's
    entry = onset_entry(cal, scenario)
    rivals = _rivals(best, candidates, cal, scenario)
    onset_fit, onset_profile, late_range = _onset_answer(
        problem, candidates, n, n_eff, cal, entry, rivals) if onset else (None, None, None)
    refitted = onset_fit is not None and not onset_fit.get('from_start')
    if refitted:
        best, bounds = candidates[0], ['']
    bounds = _widened(problem, best, bounds, free, bootstrap if not refitted else 0, seed,
                      late_range)
    d = Diagnosis(model=model, window=problem.window, candidates=candidates, n_eff=n_eff,
                  evaluations=problem.evaluations, recorded=dict(problem.recorded, t=problem.t),
                  fit_rms=math.sqrt(best.rss / n), bounds=bounds, onset=onset_fit,
                  onset_profile=onset_profile,
                  rivals=sorted(set(rivals) - {best.fault}))
    _warn(d, second, onset_fit, bounds)
    if model_form:
        apply_model_form(d, cal, free, entry if refitted else scenario, problem)
    return d


def _verdict_interval(problem: Problem, best: Candidate, results: list, free: list[str],
                      n: int) -> list[str]:
    """The verdict's likelihood-ratio interval per fault, set on ``best``; returns the
    one-sided bound each supports ('' where it is two-sided; none for healthy)."""
    if best.fault == HEALTHY:
        return []
    hyp, x, res, jac = next(r for r in results if '+'.join(r[0]) == best.fault)
    n_own = effective_n(res, len(SIGNALS))
    ivs = [ratio_interval(problem, hyp, i, x, free, res, n, n_own, jac)
           for i in range(len(hyp))]
    best.interval = ivs[0] if len(ivs) == 1 else ivs
    return [_one_sided(f, iv) for f, iv in zip(hyp, ivs)]


def _widened(problem: Problem, best: Candidate, bounds: list[str], free: list[str],
             bootstrap: int, seed: int, late_range: tuple[float, float] | None) -> list[str]:
    """The verdict's interval from ``bootstrap`` refits where asked (they refit faults present
    from the start: not an onset's), joined with ``late_range`` where the fault may have begun
    any time up to the onset interval's end (and where that reaches the catalog's end the
    answer is a one-sided bound); returns the bounds."""
    if bootstrap and best.fault != HEALTHY:
        boot = bootstrap_intervals(problem, best, free, bootstrap, seed)
        best.interval = boot[0] if len(boot) == 1 else boot
    if late_range is not None:
        best.interval = (min(best.interval[0], late_range[0]),
                         max(best.interval[1], late_range[1]))
        bounds = [_one_sided(best.fault, best.interval)]
    return bounds


def _rivals(best: Candidate, candidates: list[Candidate], cal: Mapping[str, Any] | None,
            scenario: str | None) -> list[str]:
    """The single faults the run cannot tell from the verdict: within PAIR_EVIDENCE of it in
    the information criterion and worth reporting, from the start or (``onset``) from an onset
    of their own."""
    if best.fault == HEALTHY or len(best.faults) > 1:
        return []
    return [c.fault for c in candidates[1:] if len(c.faults) == 1
            and c.score - best.score < PAIR_EVIDENCE
            and _detectable(c, cal=cal, scenario=scenario)]


def _onset_answer(problem: Problem, candidates: list[Candidate], n: int, n_eff: float,
                  cal: Mapping[str, Any] | None, entry: str, rivals: list[str]
                  ) -> tuple[dict | None, Any, tuple[float, float] | None]:
    """When the verdict's fault began (:func:`.onset.fit_onset`, sizes as the verdict states
    them with the onset entry ``entry`` of ``cal``): (the onset answer, its profile, the
    severity range of a fault that may have begun any time up to the onset interval's end --
    what fits from the start or from that late, :func:`.onset.severity_range`). The answer
    refits the verdict at the onset unless the fit from the start stands and only when the
    fault began is in doubt (``from_start``)."""
    from .onset import fit_onset
    onset_fit = fit_onset(problem, candidates, n, n_eff,
                          lambda f, s: reported_severity(cal, f, s, entry),
                          widen=onset_widen(cal, entry), rivals=rivals)
    if onset_fit is None:
        return None, None, None
    # (the factor is set for 1 - alpha of the calibration's onset units; without it the
    # interval is the noise's 95 % likelihood-ratio one)
    onset_fit['confidence'] = 1.0 - alpha_of(cal) if cal is not None else 0.95
    return onset_fit, onset_fit.pop('profile', None), onset_fit.pop('severity_range', None)


def _warn(d: Diagnosis, second: Candidate | None, onset_fit: dict | None,
          bounds: list[str]) -> None:
    """What the answer cannot say, in the diagnosis' warnings: two faults at once, an onset
    or a severity the flight does not pin."""
    if second is not None:
        d.verdict = UNEXPLAINED
        d.warnings.append(f'unexplained: two faults at once ({second.fault}) fit better than '
                          f'{d.best.fault} alone by {d.best.score - second.score:.0f} in the '
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
    from .calibration_set import from_g, severity_at, to_g
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


def _verdict_candidate(candidates: list[Candidate], by_name: Mapping[str, Candidate],
                       cal: Mapping[str, Any] | None, scenario: str | None) -> Candidate:
    """The verdict among ``candidates`` (best score first): a pair only with both faults
    worth reporting and PAIR_EVIDENCE better than each of its singles (else the ranking goes
    on to them); the first single fault if it is worth reporting, else healthy.

    Worth reporting: beyond the flight's verdict floor, or DETECTABLE of its alarm severity
    without a flight calibration (below it is the model's own mismatch -- a healthy HD unit
    fits a 2 % null bias under SQ -- or a fault below what the flight can show). A single
    fault below it never hands the run to the next hypothesis: on a flight where SQ's
    mismatch looked like a small gain loss (0.053, below its floor), the walk down the
    ranking named the next fault above its own floor (a supply loss of 0.073) in every
    healthy unit. The size is the one the answer would state (:func:`.modelform.
    reported_severity`), which the detection limits are in: SQ reads a leak on the paper
    flight ~10 % low, and a 1.7 x leak (limit 1.585 x), fitted at 1.45-1.54, was called
    healthy (measured)."""
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


__all__ = ['diagnose', 'Diagnosis', 'Candidate', 'DIAGNOSABLE', 'HEALTHY', 'UNEXPLAINED']
