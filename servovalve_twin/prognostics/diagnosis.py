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
likelihood-ratio interval along its severity (:func:`_ratio_interval`): a fit that stops on a
flat stretch of the cost -- static friction beyond the break-away the run reaches -- has a
zero Jacobian there and a Jacobian interval of zero width. With ``bootstrap`` = N, the
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
(:func:`_fit_onset`). What the answer's confidence counts -- the model-form calibration, the
goodness of fit, identifiability -- is doc/explanation/diagnosis.md.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ModelError, TwinError
from ..physics.faults import FAULTS, combine
from ..physics.params import PARAM_FIELDS, PARAM_NAMES, EhaParams
from ..physics.scenario import Profile, Scenario
from ..physics.simulate import simulate
from ..physics.signals import MEASURED
from ..physics.valves import get_monitor_model

#: the catalog faults a simplified model can see (HD's geometry, e.g. clearance, it has not)
DIAGNOSABLE = tuple(n for n, f in FAULTS.items()
                    if PARAM_FIELDS[f.param].metadata['group'] != 'hd')
SIGNALS = MEASURED
#: residual scales [SI]: about SQ's RMS error against HD on the paper scenario
#: (doc/results/against-hd.md)
RESIDUAL_SCALE = {'xj': 2.0e-4, 'dxj': 3.0e-3, 'p12': 2.0e5}
#: nuisance factors on the design values
FREE_BOUNDS = (0.5, 2.0)
BLOCK_ROWS = 50
HEALTHY = 'healthy'
UNEXPLAINED = 'unexplained'
#: catalog faults a simplified model cannot hypothesise (HD geometry it has not), and the
#: verdicts they are read as (measured on HD units, bench/bench_diagnosis.py: clearance growth
#: as leakage growth or supply loss): such a verdict says it is also consistent with them
CONFUSABLE = {'leakage_growth': ('clearance_growth',), 'supply_loss': ('clearance_growth',)}
#: no hypothesis explains a run whose best fit's RMS exceeds UNEXPLAINED_FACTOR times the
#: REFERENCE_QUANTILE of the right hypotheses' fits in the calibration set (the quantile, not
#: the maximum: a few fits of the set itself stop in a wrong valley)
REFERENCE_QUANTILE = 0.98
UNEXPLAINED_FACTOR = 1.5
#: the smallest fault reported, as a fraction of the way from healthy to its alarm severity in
#: the fault's calibration coordinate (:func:`.calibration.to_g`)
DETECTABLE = 0.2
#: how much lower (better) a pair's score must be than each of its two single faults' to be
#: reported: "very strong" evidence on Kass and Raftery's BIC scale
PAIR_EVIDENCE = 10.0
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


@dataclasses.dataclass
class Candidate:
    """One hypothesis fitted: ``fault`` (or 'healthy'), its severity and 95 % interval, the
    information criterion (``score``, lower is better), RSS, nuisance factors."""

    fault: str
    severity: float | list[float] | None      # a list for a pair, one per fault
    interval: tuple[float, float] | list[tuple[float, float]] | None
    score: float
    rss: float
    free: dict[str, float]
    fitted: dict[str, np.ndarray]
    #: the fit's own severity and 95 % interval, before a model-form correction replaced them
    raw: tuple[Any, Any] | None = None

    @property
    def faults(self) -> tuple[str, ...]:
        """The catalog faults of the hypothesis: () for healthy, one, or two for a pair."""
        return () if self.fault == HEALTHY else tuple(self.fault.split('+'))

    @property
    def severities(self) -> list[float]:
        """One severity per fault of :attr:`faults` (a single fault's as a list of one)."""
        if self.severity is None:
            return []
        return self.severity if isinstance(self.severity, list) else [self.severity]

    @property
    def intervals(self) -> list[tuple[float, float]]:
        """One interval per fault of :attr:`faults`."""
        if self.interval is None:
            return []
        return self.interval if isinstance(self.interval, list) else [self.interval]

    def to_json(self) -> dict[str, Any]:
        return dict(fault=self.fault, severity=self.severity,
                    interval=_interval_json(self.interval), score=self.score)


def _interval_json(interval):
    if interval is None:
        return None
    if isinstance(interval, list):
        return [list(i) for i in interval]
    return list(interval)


@dataclasses.dataclass
class Diagnosis:
    model: str
    window: tuple[float, float]
    candidates: list[Candidate]          # best first
    n_eff: float
    evaluations: int
    recorded: dict[str, np.ndarray]
    #: what was assumed or doubted (one line each), in the JSON and on stderr
    warnings: list[str] = dataclasses.field(default_factory=list)
    #: 'unexplained' when no hypothesis fits as a right one does (or the nominal parameters
    #: are unknown); otherwise the best candidate's name
    verdict: str = ''
    #: the goodness of fit of the best candidate: its RMS of normalised residuals and the
    #: share of right fits in the calibration set that fitted as badly (None: no calibration)
    fit_rms: float = math.nan
    p_value: float | None = None
    fit_limit: float | None = None               # the RMS beyond which it is unexplained
    #: the verdict interval's confidence and what it counts
    confidence: float = 0.95
    interval_counts: str = 'measurement noise'
    #: the model-form calibration applied (None: none, the intervals count the noise only),
    #: and the calibration scenario whose own entries it used (None: the pooled ones)
    calibration: dict[str, Any] | None = None
    calibration_scenario: str | None = None
    #: when the verdict's fault began ({'t', 'interval'} [s]), None: from the start (or not
    #: asked)
    onset: dict[str, Any] | None = None
    #: per fault of the verdict: '' where the data pin its severity, else the one-sided bound
    #: they support ('static_friction >= 12.3': the likelihood is flat beyond)
    bounds: list[str] = dataclasses.field(default_factory=list)

    @property
    def identifiable(self) -> bool:
        return not any(self.bounds)

    @property
    def also_consistent_with(self) -> list[str]:
        """Catalog faults outside the hypotheses that the verdict cannot be told from."""
        if self.verdict:
            return []
        return sorted({o for f in self.best.faults for o in CONFUSABLE.get(f, ())})

    @property
    def best(self) -> Candidate:
        return self.candidates[0]

    def to_json(self) -> dict[str, Any]:
        """The JSON of `diagnose --json`: the verdict first, every candidate after it."""
        b = self.best
        unexplained = self.verdict == UNEXPLAINED
        return dict(fault=self.verdict or b.fault,
                    severity=None if unexplained else b.severity,
                    interval=None if unexplained else _interval_json(b.interval),
                    confidence=self.confidence, interval_counts=self.interval_counts,
                    fit=dict(rms=self.fit_rms, p_value=self.p_value, limit=self.fit_limit),
                    identifiable=self.identifiable, bounds=[b for b in self.bounds if b],
                    also_consistent_with=self.also_consistent_with,
                    onset=None if unexplained else self.onset,
                    candidates=[c.to_json() for c in self.candidates], model=self.model,
                    window=list(self.window), warnings=list(self.warnings))


class _Problem:
    """The recorded run cut to the window, and the model run for one parameter set."""

    def __init__(self, signals: Mapping[str, np.ndarray], design: EhaParams, model: str,
                 control_period: float, window: tuple[float, float] | None,
                 start: float | None = None):
        missing = [s for s in ('t', 'com', 'fr', 'psr') + SIGNALS
                   if s not in signals or not np.all(np.isfinite(signals[s]))]
        if missing:
            raise TwinError(f'the run lacks {", ".join(missing)} (a diagnosis needs the '
                            'recorded /com, /fr, /psr, /xj, /dxj and /p12 at every 1 ms row)')
        get_monitor_model(model)
        self.model = model
        # derived parameters (C4_alpha from CLk, ...) derive again under each hypothesis, as
        # they do when the twin injects a fault; a bag's provenance lists them resolved
        self.design = design.replace(**{n: None for n in PARAM_NAMES
                                        if PARAM_FIELDS[n].default is None})
        self.control_period = control_period
        t = np.asarray(signals['t'], dtype=float)
        ms = np.rint(t * 1000).astype(np.int64)
        t_last = ms[-1] / 1000
        t0, t1 = window if window is not None else (0.0, t_last)
        if not (0.0 <= t0 < t1 <= t_last + 1e-9):
            raise TwinError(f'window {t0:g}:{t1:g} s lies outside the run [0, {t_last:g}] s '
                            '(T0 < T1 needed)')
        self.window = (float(t0), float(t1))
        start = 0.0 if start is None else float(start)
        if not 0.0 <= start <= t0 + 1e-9:
            raise TwinError(f'start {start:g} s must lie in [0, {t0:g}] (the window start)')
        n_end = int(round(t1 * 1000))
        n_start = int(round(start * 1000))
        # the model runs from `start`, time shifted to 0, from the recorded jack state there
        # (the spool and flapper from rest: they settle within milliseconds); a whole run
        # starts at rest, where this is the rest state itself
        self.initial = {s: float(signals[s][n_start]) for s in ('xj', 'dxj')}
        # inputs in force from each 1 ms row on (piecewise constant, as the twin holds them)
        profiles = {s: Profile('steps', tuple(zip(((ms[n_start:n_end + 1] - n_start) / 1000
                                                   ).tolist(),
                                                  np.asarray(signals[s][n_start:n_end + 1],
                                                             dtype=float).tolist())))
                    for s in ('com', 'fr', 'psr')}
        self.scenario = Scenario(name='recorded', duration=(n_end - n_start) / 1000, **profiles)
        keep = (ms >= int(round(t0 * 1000))) & (ms <= n_end)
        self.rows = np.flatnonzero(keep)
        self.model_rows = self.rows - n_start
        self.recorded = {s: np.asarray(signals[s], dtype=float)[self.rows] for s in SIGNALS}
        self.t = t[self.rows]
        self.evaluations = 0
        self._runs: dict[tuple, dict[str, np.ndarray] | None] = {}
        self.t_start = n_start / 1000                  # run time of the model's t = 0

    def params(self, faults: Sequence[str], severities: Sequence[float],
               free: Mapping[str, float]) -> EhaParams:
        nominal = self.design.replace(**{k: self.design.value(k) * v for k, v in free.items()})
        return combine(nominal, dict(zip(faults, severities)))

    def run(self, params: EhaParams, events: tuple = ()) -> dict[str, np.ndarray] | None:
        """The model's window rows for ``params`` (None if the model failed); each parameter
        set runs once -- the fitted signals of a hypothesis are those of its last solver
        evaluations, not a run more. ``events``: faults scheduled during the run, ``(at [s,
        run time], fault, severity)`` each (an onset)."""
        key = (params, events)
        if key not in self._runs:
            self.evaluations += 1
            scn = self.scenario if not events else dataclasses.replace(
                self.scenario, faults=tuple(dict(at=at - self.t_start, fault=f, severity=sev)
                                            for at, f, sev in events))
            try:
                r = simulate(self.model, scn, params=params, ecu_period=self.control_period,
                             initial=self.initial)
                self._runs[key] = {s: r[s][self.model_rows] for s in SIGNALS}
            except ModelError:
                self._runs[key] = None
        return self._runs[key]

    def residuals(self, fitted: dict[str, np.ndarray] | None,
                  recorded: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        recorded = self.recorded if recorded is None else recorded
        if fitted is None:                      # the model failed here: far from any fit
            return np.full(len(SIGNALS) * len(self.rows), 1e3)
        return np.concatenate([(fitted[s] - recorded[s]) / RESIDUAL_SCALE[s] for s in SIGNALS])


def _start_grid(name: str, n: int = 7) -> list[float]:
    """Severities to start from: geometric for multipliers, even for fractions and values."""
    f = FAULTS[name]
    if f.kind == 'scale':
        grid = [f.lo * (f.hi / f.lo) ** q for q in np.linspace(0.0, 1.0, n)]
    else:
        grid = list(np.linspace(f.lo, f.hi, n))
    return [float(g) for g in grid]


def _effective_n(res: np.ndarray, n_signals: int) -> float:
    """n*(1 - rho)/(1 + rho) with rho the mean lag-1 autocorrelation of each signal's
    residual (AR(1)); at least 10."""
    rhos = []
    for r in np.split(res, n_signals):
        r = r - r.mean()
        den = float(np.dot(r, r))
        rhos.append(float(np.dot(r[1:], r[:-1])) / den if den > 0 else 0.0)
    rho = min(max(float(np.mean(rhos)), 0.0), 0.999)
    return max(10.0, len(res) * (1.0 - rho) / (1.0 + rho))


def _fit(problem: _Problem, faults: Sequence[str], free: Sequence[str],
         recorded: Mapping[str, np.ndarray] | None = None,
         starts: Sequence[Sequence[float]] | None = None):
    """Least squares over the faults' severities + nuisance factors; returns (x, residuals,
    jacobian). ``starts``: candidate start points, the best of which is refined (default: a
    coarse grid of a single fault's severity, nuisance at design values)."""
    from scipy.optimize import least_squares
    specs = [FAULTS[f] for f in faults]
    nf = len(specs)
    lo = [f.lo for f in specs] + [FREE_BOUNDS[0]] * len(free)
    hi = [f.hi for f in specs] + [FREE_BOUNDS[1]] * len(free)

    def fun(x):
        fr = {k: float(v) for k, v in zip(free, x[nf:])}
        return problem.residuals(problem.run(problem.params(faults, [float(v) for v in x[:nf]],
                                                            fr)), recorded)

    if not lo:                                   # healthy, nothing free: no fit to make
        return np.zeros(0), fun(np.zeros(0)), np.zeros((len(problem.rows) * 3, 0))
    if starts is None:
        design = [1.0] * len(free)
        starts = [[g] + design for g in _start_grid(faults[0])] if nf == 1 else [
            [FAULTS[f].healthy for f in faults] + design]
    starts = [np.clip(np.asarray(x, dtype=float), lo, hi) for x in starts]
    if len(starts) > 1:
        costs = [float(np.sum(fun(x) ** 2)) for x in starts]
        x0 = starts[int(np.argmin(costs))]
    else:
        x0 = starts[0]
    scale = [(h - l) / 10.0 for l, h in zip(lo, hi)]
    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, diff_step=1e-3,
                        method='trf', xtol=1e-6, ftol=1e-8, max_nfev=60 * max(1, nf))
    return sol.x, sol.fun, sol.jac


def diagnose(signals: Mapping[str, np.ndarray], design: EhaParams, *, control_period: float,
             model: str = 'SQ', faults: Sequence[str] = DIAGNOSABLE,
             window: tuple[float, float] | None = None, free: Sequence[str] = (),
             bootstrap: int = 0, seed: int = 0, pairs: bool = False,
             start: float | None = None, model_form: bool = True,
             onset: bool = False, scenario: str | None = None) -> Diagnosis:
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
    :param onset: also fit when a single-fault verdict began (see :func:`_fit_onset`)
    :param scenario: the calibration scenario the run flew (``'bit'``, ``'paper'``), whose own
        model-form calibration then applies (:func:`.calibration.fault_calibration`); a bag's
        is found by :func:`..apps.diagnose.calibration_scenario`
    """
    for f in faults:
        if f not in FAULTS:
            raise TwinError(f'unknown fault {f!r}; expected one of {list(DIAGNOSABLE)}')
        if f not in DIAGNOSABLE:
            raise TwinError(f'fault {f!r} acts on HD geometry a simplified model does not '
                            f'have; expected one of {list(DIAGNOSABLE)}')
    for p in free:
        if p not in PARAM_NAMES:
            raise TwinError(f'--free: unknown parameter {p!r}')
    if any(FAULTS[f].param in free for f in faults):
        raise TwinError('--free names a parameter a fault hypothesis estimates')
    # catalog order, so that a pair has one name whatever order the user gave
    faults = [f for f in DIAGNOSABLE if f in set(faults)]
    if pairs and len(faults) < 2:
        raise TwinError('--pairs needs at least two faults to pair')
    free = list(free)
    problem = _Problem(signals, design, model, control_period, window, start)
    results = [((), *_fit(problem, (), free))]
    singles = {}
    for fault in faults:
        x, res, jac = _fit(problem, (fault,), free)
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
                    [ga, gb] + [1.0] * len(free)
                    for ga in _start_grid(a, PAIR_GRID) for gb in _start_grid(b, PAIR_GRID)]
                results.append(((a, b), *_fit(problem, (a, b), free, starts=starts)))
    n = len(results[0][2])
    n_eff = _effective_n(results[0][2], len(SIGNALS))
    candidates = [_candidate(problem, *r, free, n, n_eff) for r in results]
    candidates.sort(key=lambda c: c.score)
    # the verdict: the best-scoring hypothesis that is healthy or of faults of a size worth
    # reporting; a fault fitted below DETECTABLE of its alarm severity is the model's own
    # mismatch (a healthy HD unit fits a 2 % null bias under SQ), so it yields
    by_name = {c.fault: c for c in candidates}
    best = next(c for c in candidates if c.fault == HEALTHY or (
        _detectable(c) and all(by_name[f].score - c.score >= PAIR_EVIDENCE
                               for f in c.faults if len(c.faults) == 2)))
    candidates.remove(best)
    candidates.insert(0, best)
    second = None
    if not pairs and not onset and len(best.faults) == 1 and len(faults) > 1:
        second = _second_fault(problem, best, singles, candidates, free, n, n_eff)
        if second is not None:
            candidates.insert(1, second)
    if best.fault != HEALTHY:
        hyp, x, res, jac = next(r for r in results if '+'.join(r[0]) == best.fault)
        n_own = _effective_n(res, len(SIGNALS))
        ivs = [_ratio_interval(problem, hyp, i, x, free, res, n, n_own, jac)
               for i in range(len(hyp))]
        best.interval = ivs[0] if len(ivs) == 1 else ivs
        bounds = [_one_sided(f, iv) for f, iv in zip(hyp, ivs)]
    else:
        bounds = []
    onset_fit = _fit_onset(problem, candidates, n, n_eff) if onset else None
    if onset_fit is not None:
        best, bounds = candidates[0], ['']
    # (the bootstrap refits faults present from the start: not an onset's)
    if bootstrap and best.fault != HEALTHY and onset_fit is None:
        boot = _bootstrap_intervals(problem, best, free, bootstrap, seed)
        best.interval = boot[0] if len(boot) == 1 else boot
    d = Diagnosis(model=model, window=problem.window, candidates=candidates, n_eff=n_eff,
                  evaluations=problem.evaluations, recorded=dict(problem.recorded, t=problem.t),
                  fit_rms=math.sqrt(best.rss / n), bounds=bounds, onset=onset_fit)
    if second is not None:
        d.verdict = UNEXPLAINED
        d.warnings.append(f'unexplained: two faults at once ({second.fault}) fit better than '
                          f'{best.fault} alone by {best.score - second.score:.0f} in the '
                          f'information criterion (more than {SECOND_FAULT_EVIDENCE:g}): '
                          'outside the single-fault hypotheses; diagnose with --pairs')
    if any(bounds):
        d.warnings.append('not identifiable on this run: ' + '; '.join(b for b in bounds if b)
                          + ' (the fit does not change beyond it: only a flight that excites '
                          'it more can pin it)')
    if model_form:
        _apply_model_form(d, free, scenario)
    return d


def _candidate(problem: _Problem, hyp: tuple[str, ...], x: np.ndarray, res: np.ndarray,
               jac: np.ndarray, free: Sequence[str], n: int, n_eff: float) -> Candidate:
    """A fitted hypothesis as a candidate: its score, severities, Jacobian intervals."""
    rss = float(np.dot(res, res))
    score = n_eff * math.log(max(rss, 1e-300) / n) + len(x) * math.log(n_eff)
    sevs = [float(v) for v in x[:len(hyp)]]
    # the interval's correlation is that of the hypothesis' own residuals: white where the
    # model fits but for noise, strongly correlated where it cannot follow
    n_own = _effective_n(res, len(SIGNALS))
    intervals = [_jacobian_interval(f, i, x, res, jac, n, n_own) or (FAULTS[f].lo, FAULTS[f].hi)
                 for i, f in enumerate(hyp)]
    freev = dict(zip(free, x[len(hyp):].tolist()))
    fitted = problem.run(problem.params(hyp, sevs, freev))
    if len(hyp) == 1:
        sev, interval = sevs[0], intervals[0]
    elif hyp:
        sev, interval = sevs, intervals
    else:
        sev = interval = None
    return Candidate('+'.join(hyp) or HEALTHY, sev, interval, score, rss, freev, fitted or {})


def _second_fault(problem: _Problem, best: Candidate, singles: Mapping[str, np.ndarray],
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
        cand = _candidate(problem, hyp, *_fit(problem, hyp, free, starts=[start]), free, n,
                          n_eff)
        # both faults of at least the mild size: a second fault fitted near the detection
        # floor is absorbing the model's mismatch and the nuisance, not a fault
        if best.score - cand.score >= SECOND_FAULT_EVIDENCE and _detectable(
                cand, SECOND_FAULT_SIZE) and (
                found is None or cand.score < found.score):
            found = cand
    return found


def _apply_model_form(d: Diagnosis, free: Sequence[str], scenario: str | None = None
                      ) -> None:
    """The calibration's bias correction and model-form spread on the verdict, and the
    goodness-of-fit test (see :mod:`.calibration`)."""
    from .calibration import calibration_for, gof_p_value
    cal = calibration_for(d.model, free)
    if cal is None:
        d.warnings.append(f'no model-form calibration for {d.model} with free '
                          f'{",".join(sorted(free)) or "none"}: the interval counts the '
                          'measurement noise only')
        return
    d.calibration = cal
    d.calibration_scenario = scenario if scenario in (cal.get('by_scenario') or {}) else None
    d.p_value = gof_p_value(cal, d.fit_rms)
    d.fit_limit = UNEXPLAINED_FACTOR * float(np.quantile(cal['rms'], REFERENCE_QUANTILE))
    if d.fit_rms > d.fit_limit:
        d.verdict = UNEXPLAINED
        d.warnings.append(f'no hypothesis explains the run: the best ({d.best.fault}) fits with '
                          f'RMS {d.fit_rms:.3g} of the residual scales, beyond {d.fit_limit:.3g} '
                          f'({UNEXPLAINED_FACTOR:g} x the {REFERENCE_QUANTILE:.0%} quantile of '
                          f'right hypotheses in the calibration set; p = {d.p_value:.2g})')
        return
    best = d.best
    if best.fault == HEALTHY:
        return
    best.raw = (best.severity, best.interval)
    sevs, ivs = [], []
    for f, s, iv in zip(best.faults, best.severities, best.intervals):
        s, iv, _ = model_form_estimate(cal, f, s, iv, scenario)
        sevs.append(s)
        ivs.append(iv)
    best.severity = sevs[0] if len(sevs) == 1 else sevs
    best.interval = ivs[0] if len(ivs) == 1 else ivs
    d.confidence = 0.9
    d.interval_counts = 'measurement noise and the model-form error calibrated against HD' + (
        f' on this flight ({d.calibration_scenario})' if d.calibration_scenario else '')


def model_form_estimate(cal: Mapping[str, Any], fault: str, severity: float,
                        interval95: tuple[float, float], scenario: str | None = None
                        ) -> tuple[float, tuple[float, float], float]:
    """A fault's severity less the calibrated bias, its 90 % interval with the model-form
    spread (the fit's 95 % interval read as a standard error), and that spread as a relative
    standard deviation of the distance from healthy (what :func:`..prognosis.prognose` takes
    as ``model_sigma``). Unchanged, with a spread of 0, for a fault the calibration lacks.
    ``scenario``: the calibration scenario the flight is (its own entry, where there is one)."""
    from .calibration import Z90, bias_at, fault_calibration, from_g, to_g
    c = fault_calibration(cal, fault, scenario)
    spec = FAULTS[fault]
    lo, hi = interval95
    if c is None:
        return severity, (lo, hi), 0.0
    se = (to_g(fault, hi) - to_g(fault, lo)) / (2 * 1.96)
    g = to_g(fault, severity)
    g = g - bias_at(c, g)
    half = Z90 * math.hypot(se, c['sigma'])
    est = min(max(from_g(fault, g), spec.lo), spec.hi)
    iv = (max(from_g(fault, g - half), spec.lo), min(from_g(fault, g + half), spec.hi))
    # the spread in g as a relative error of s - h: dg * s/(s - h) for a multiplier (g = ln
    # s/h), dg * span/|s - h| for a fraction or value; capped where s is near healthy
    dist = max(abs(est - spec.healthy), 0.05 * abs(spec.demo - spec.healthy))
    rel = c['sigma'] * (est if spec.kind == 'scale' else abs(spec.demo - spec.healthy)) / dist
    return est, iv, float(min(rel, 0.5))


#: the onset screen: candidate instants over the window per single-fault hypothesis (the
#: best is then refined by golden section), and severities each instant's fit may start from
ONSET_GRID = 9
ONSET_STARTS = 5


class _OnsetProfile:
    """One fault's severity refitted with the fault starting at each tried instant tau."""

    def __init__(self, problem: _Problem, cand: Candidate):
        self.problem, self.cand = problem, cand
        self.fault = cand.faults[0]
        self.nominal = problem.params((), [], cand.free)
        self.fits: dict[float, tuple[float, float, Any]] = {}

    def cost(self, tau: float) -> float:
        from scipy.optimize import least_squares
        tau = round(float(tau), 4)
        if tau not in self.fits:
            spec = FAULTS[self.fault]

            def fun(x):
                return self.problem.residuals(self.problem.run(
                    self.nominal, ((tau, self.fault, float(x[0])),)))
            # started from the best of the from-start fit and a coarse grid: the cost can be
            # far from convex (a supply loss from 0.6 s: RSS 1.9e5 at 0.2, 2.8e4 at the true
            # 0.3, 2.7e6 at 0.4), and from the from-start fit (near 0) the solver stalled
            starts = [min(max(float(self.cand.severity), spec.lo), spec.hi)] + _start_grid(
                self.fault, ONSET_STARTS)
            x0 = min(starts, key=lambda v: float(np.sum(fun([v]) ** 2)))
            sol = least_squares(fun, [x0], bounds=([spec.lo], [spec.hi]),
                                x_scale=[(spec.hi - spec.lo) / 10.0], diff_step=1e-3,
                                xtol=1e-6, ftol=1e-8, max_nfev=30)
            self.fits[tau] = (float(sol.x[0]), float(sol.fun @ sol.fun), sol)
        return self.fits[tau][1]

    def best(self) -> tuple[float, float, float, Any]:
        tau = min(self.fits, key=lambda t: self.fits[t][1])
        sev, rss, sol = self.fits[tau]
        return tau, sev, rss, sol


def _fit_onset(problem: _Problem, candidates: list[Candidate], n: int, n_eff: float
               ) -> dict[str, Any] | None:
    """A change point: each single-fault hypothesis starting at an instant tau of the window
    instead of from the start, its severity refitted at each tau of a coarse grid; the best
    fault whose severity is of a size worth reporting (:func:`_sized`) has its tau refined by
    golden section. Reported when it beats the best candidate from the
    start by PAIR_EVIDENCE in BIC (tau, and the severity too against healthy, are parameters
    more); the taus whose RSS stays within the 95 % likelihood-ratio limit are its interval.
    The onset candidate is then moved to the front as the verdict, with its severity and
    Jacobian interval at tau. About 100 model runs per hypothesis."""
    singles = [c for c in candidates if len(c.faults) == 1]
    if not singles:
        return None
    t0, t1 = problem.window
    grid = np.linspace(max(t0, problem.t_start) + 0.005, t1 - 0.05, ONSET_GRID)
    profiles = [_OnsetProfile(problem, c) for c in singles]
    for prof in profiles:
        for t in grid:
            prof.cost(t)
    # a change point of a fault too small to report is the mismatch's, as from the start (a
    # static friction below its limit read as a 1.2-1.5 x dynamic friction from a wrong
    # instant: measured)
    sized = [pr for pr in profiles if _sized(pr.fault, pr.best()[1])]
    if not sized:
        return None
    prof = min(sized, key=lambda pr: pr.best()[2])
    k = int(np.argmin([prof.cost(t) for t in grid]))
    a, b = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)])
    g = (math.sqrt(5) - 1) / 2
    for _ in range(8):
        c, d = b - g * (b - a), a + g * (b - a)
        if prof.cost(c) <= prof.cost(d):
            b = d
        else:
            a = c
    tau, sev, rss, sol = prof.best()
    ref = candidates[0]
    extra = 1 + (1 if ref.fault == HEALTHY else 0)
    gain = n_eff * math.log(max(ref.rss, 1e-300) / max(rss, 1e-300)) - extra * math.log(n_eff)
    if gain < PAIR_EVIDENCE:
        return None
    limit = rss * (1.0 + CHI2_95 * (n / n_eff) / max(n - 2, 1))
    # the interval: the tried instants that bracket those within the limit (the limit is
    # crossed somewhere between an instant inside and its neighbour outside)
    tried = sorted(prof.fits)
    inside = [t for t in tried if prof.fits[t][1] <= limit]
    below = [t for t in tried if t < min(inside) and prof.fits[t][1] > limit]
    above = [t for t in tried if t > max(inside) and prof.fits[t][1] > limit]
    lo = max(below) if below else t0
    hi = min(above) if above else t1
    spec = FAULTS[prof.fault]
    n_own = _effective_n(sol.fun, len(SIGNALS))
    iv = _jacobian_interval(prof.fault, 0, sol.x, sol.fun, sol.jac, n, n_own) or (spec.lo,
                                                                                  spec.hi)
    cand = prof.cand
    cand.severity, cand.interval, cand.rss = sev, iv, rss
    cand.fitted = problem.run(prof.nominal, ((tau, prof.fault, sev),)) or {}
    candidates.remove(cand)
    candidates.insert(0, cand)
    return dict(t=float(tau), interval=[float(lo), float(hi)], fault=prof.fault)


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


def _sized(fault: str, severity: float, fraction: float = DETECTABLE) -> bool:
    """``severity`` at least ``fraction`` (DETECTABLE) of the way from healthy to the fault's
    alarm value, in its calibration coordinate."""
    from .calibration import to_g
    return abs(to_g(fault, severity)) >= fraction * abs(to_g(fault, FAULTS[fault].demo))


def _detectable(c: Candidate, fraction: float = DETECTABLE) -> bool:
    """Every fault of ``c`` of a size worth reporting (:func:`_sized`)."""
    return all(_sized(f, s, fraction) for f, s in zip(c.faults, c.severities))


def _jacobian_interval(fault, i, x, res, jac, n, n_eff) -> tuple[float, float] | None:
    """95 % interval of the severity x[i] of ``fault`` from the fit's Jacobian; None where the
    residuals do not move with it at the fit (a flat stretch: static friction beyond the
    break-away a run reaches), where the Jacobian says nothing."""
    spec = FAULTS[fault]
    if not np.any(jac[:, i]):
        return None
    k = len(x)
    s2 = float(np.dot(res, res)) / max(n - k, 1)
    jtj = jac.T @ jac
    try:
        cov = np.linalg.pinv(jtj) * s2 * (n / n_eff)
        half = 1.96 * math.sqrt(max(float(cov[i, i]), 0.0))
    except np.linalg.LinAlgError:
        half = math.inf
    if not math.isfinite(half):
        return (spec.lo, spec.hi)
    return (max(spec.lo, float(x[i]) - half), min(spec.hi, float(x[i]) + half))


#: chi-square with one degree of freedom at 95 %
CHI2_95 = 3.841


def _ratio_interval(problem: _Problem, faults: Sequence[str], i: int, x: np.ndarray,
                    free: Sequence[str], res: np.ndarray, n: int, n_eff: float,
                    jac: np.ndarray) -> tuple[float, float]:
    """The verdict's 95 % interval for severity ``i``: the severities whose RSS, the rest held
    at the fit, stays within ``CHI2_95*s^2*n/n_eff`` of the fit's (a likelihood-ratio reading
    with the residual variance and correlation of the fit), joined with the Jacobian's. Where
    the cost is flat the ratio interval spans the flat stretch; where it is a parabola the two
    agree. About 25 model runs."""
    spec = FAULTS[faults[i]]
    rss0 = float(np.dot(res, res))
    limit = rss0 + CHI2_95 * rss0 / max(n - len(x), 1) * (n / n_eff)
    nf = len(faults)
    fr = {k: float(v) for k, v in zip(free, x[nf:])}

    def inside(v: float) -> bool:
        sev = [float(s) for s in x[:nf]]
        sev[i] = v
        r = problem.residuals(problem.run(problem.params(faults, sev, fr)))
        return float(np.dot(r, r)) <= limit

    x0 = float(x[i])
    ends = []
    for bound in (spec.lo, spec.hi):
        # step out geometrically from the fit until outside (or at the bound), then bisect
        step, last_in, out = (bound - x0) / 256.0, x0, None
        while step and out is None:
            v = x0 + step
            if abs(v - x0) >= abs(bound - x0):
                v = bound
            if inside(v):
                last_in = v
                if v == bound:
                    break
                step *= 2.0
            else:
                out = v
        for _ in range(6 if out is not None else 0):
            mid = 0.5 * (last_in + out)
            if inside(mid):
                last_in = mid
            else:
                out = mid
        ends.append(last_in)
    lo, hi = ends
    jac_iv = _jacobian_interval(faults[i], i, x, res, jac, n, n_eff)
    if jac_iv is not None:
        lo, hi = min(lo, jac_iv[0]), max(hi, jac_iv[1])
    return (float(lo), float(hi))


def _bootstrap_intervals(problem: _Problem, best: Candidate, free: list[str], n: int,
                         seed: int) -> list[tuple[float, float]]:
    """Percentile intervals (one per fault of ``best``) of ``n`` refits to the fitted signals
    plus moving blocks of the residuals."""
    rng = np.random.default_rng(seed)
    m = len(problem.rows)
    resid = {s: problem.recorded[s] - best.fitted[s] for s in SIGNALS}
    sev = []
    start = best.severities + [best.free[k] for k in free]
    for _ in range(n):
        starts = rng.integers(0, max(1, m - BLOCK_ROWS), size=-(-m // BLOCK_ROWS))
        idx = np.concatenate([np.arange(a, a + BLOCK_ROWS) for a in starts])[:m] % m
        synthetic = {s: best.fitted[s] + resid[s][idx] for s in SIGNALS}
        x, _, _ = _fit(problem, best.faults, free, synthetic, [start])
        sev.append(x[:len(best.faults)])
    lo, hi = np.percentile(np.array(sev), [2.5, 97.5], axis=0)
    return [(float(a), float(b)) for a, b in zip(lo, hi)]


__all__ = ['diagnose', 'Diagnosis', 'Candidate', 'DIAGNOSABLE', 'HEALTHY', 'UNEXPLAINED',
           'model_form_estimate']
