"""Diagnosis from a recorded run: which catalog fault, how severe, with what confidence.

Parameter estimation on a fast model, after Dalla Vedova, Maggiore and Pace (WSEAS 2014): a
simplified model of the whole actuator (default SQ), driven by the run's recorded Com, FR and
PSR through the same compiled physics as ``simulate`` (ECU sampled at the run's control
period), is fitted to the recorded XJ, DXJ and P12 once per hypothesis -- healthy, and each
catalog fault (:data:`~..physics.faults.FAULTS`) with its severity free within the catalog's
bounds -- by bounded nonlinear least squares (``scipy.optimize.least_squares``). Nuisance
parameters the user names (``free``: M, CJ, ...) are estimated alongside, as factors on their
design values in [0.5, 2].

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
:data:`DETECTABLE` (10 %) of the way from healthy to its catalog alarm severity is not reported
over healthy: that small a fit is the model's mismatch (a healthy HD unit fits a null bias of
2 % of the alarm value under SQ). ``candidates`` keep every fit, in score order after the
verdict.

Confidence. The severity's 95 % interval comes from the fit's Jacobian, ``cov = s^2
(J^T J)^-1`` inflated by ``n/n_eff`` for the correlation, or, with ``bootstrap`` = N, from N
refits to the fitted signals plus moving blocks (50 ms) of the residuals (percentiles).

The hypothesis holds over the whole simulated stretch, from t = 0 to the window's end: a flight
with one degradation level (prognosis). A fault that appears mid-run is diagnosed on a window
after its onset, with the model run faulty from the start -- a bias for faults that change the
state before the window.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ModelError, TwinError
from ..physics.faults import FAULTS, resolve
from ..physics.params import PARAM_FIELDS, PARAM_NAMES, EhaParams
from ..physics.scenario import Profile, Scenario
from ..physics.simulate import simulate
from ..physics.valves import get_monitor_model

#: the catalog faults a simplified model can see (HD's geometry, e.g. clearance, it has not)
DIAGNOSABLE = tuple(n for n, f in FAULTS.items()
                    if PARAM_FIELDS[f.param].metadata['group'] != 'hd')
SIGNALS = ('xj', 'dxj', 'p12')
#: residual scales [SI]: about SQ's RMS error against HD on the paper scenario (README table)
RESIDUAL_SCALE = {'xj': 2.0e-4, 'dxj': 3.0e-3, 'p12': 2.0e5}
#: nuisance factors on the design values
FREE_BOUNDS = (0.5, 2.0)
BLOCK_ROWS = 50
HEALTHY = 'healthy'
#: the smallest fault reported, as a fraction of the way from healthy to its alarm severity
DETECTABLE = 0.1


@dataclasses.dataclass
class Candidate:
    """One hypothesis fitted: ``fault`` (or 'healthy'), its severity and 95 % interval, the
    information criterion (``score``, lower is better), RSS, nuisance factors."""

    fault: str
    severity: float | None
    interval: tuple[float, float] | None
    score: float
    rss: float
    free: dict[str, float]
    fitted: dict[str, np.ndarray]

    def to_json(self) -> dict[str, Any]:
        return dict(fault=self.fault, severity=self.severity,
                    interval=None if self.interval is None else list(self.interval),
                    score=self.score)


@dataclasses.dataclass
class Diagnosis:
    model: str
    window: tuple[float, float]
    candidates: list[Candidate]          # best first
    n_eff: float
    evaluations: int
    recorded: dict[str, np.ndarray]

    @property
    def best(self) -> Candidate:
        return self.candidates[0]

    def to_json(self) -> dict[str, Any]:
        """The issue's schema, exactly."""
        b = self.best
        return dict(fault=b.fault, severity=b.severity,
                    interval=None if b.interval is None else list(b.interval),
                    candidates=[c.to_json() for c in self.candidates], model=self.model,
                    window=list(self.window))


class _Problem:
    """The recorded run cut to the window, and the model run for one parameter set."""

    def __init__(self, signals: Mapping[str, np.ndarray], design: EhaParams, model: str,
                 control_period: float, window: tuple[float, float] | None):
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
        n_end = int(round(t1 * 1000))
        # inputs in force from each 1 ms row on (piecewise constant, as the twin holds them)
        profiles = {s: Profile('steps', tuple(zip((ms[:n_end + 1] / 1000).tolist(),
                                                  np.asarray(signals[s][:n_end + 1],
                                                             dtype=float).tolist())))
                    for s in ('com', 'fr', 'psr')}
        self.scenario = Scenario(name='recorded', duration=n_end / 1000, **profiles)
        keep = (ms >= int(round(t0 * 1000))) & (ms <= n_end)
        self.rows = np.flatnonzero(keep)
        self.recorded = {s: np.asarray(signals[s], dtype=float)[self.rows] for s in SIGNALS}
        self.t = t[self.rows]
        self.evaluations = 0
        self._runs: dict[EhaParams, dict[str, np.ndarray] | None] = {}

    def params(self, fault: str | None, severity: float | None,
               free: Mapping[str, float]) -> EhaParams:
        nominal = self.design.replace(**{k: self.design.value(k) * v for k, v in free.items()})
        if fault is None:
            return nominal
        return nominal.replace(**resolve(fault, severity, nominal))

    def run(self, params: EhaParams) -> dict[str, np.ndarray] | None:
        """The model's window rows for ``params`` (None if the model failed); each parameter
        set runs once -- the fitted signals of a hypothesis are those of its last solver
        evaluations, not a run more."""
        if params not in self._runs:
            self.evaluations += 1
            try:
                r = simulate(self.model, self.scenario, params=params,
                             ecu_period=self.control_period)
                self._runs[params] = {s: r[s][self.rows] for s in SIGNALS}
            except ModelError:
                self._runs[params] = None
        return self._runs[params]

    def residuals(self, fitted: dict[str, np.ndarray] | None,
                  recorded: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        recorded = self.recorded if recorded is None else recorded
        if fitted is None:                      # the model failed here: far from any fit
            return np.full(len(SIGNALS) * len(self.rows), 1e3)
        return np.concatenate([(fitted[s] - recorded[s]) / RESIDUAL_SCALE[s] for s in SIGNALS])


def _start_grid(name: str) -> list[float]:
    """Severities to start from: geometric for multipliers, even for fractions and values."""
    f = FAULTS[name]
    if f.kind == 'scale':
        grid = [f.lo * (f.hi / f.lo) ** q for q in np.linspace(0.0, 1.0, 7)]
    else:
        grid = list(np.linspace(f.lo, f.hi, 7))
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


def _fit(problem: _Problem, fault: str | None, free: Sequence[str],
         recorded: Mapping[str, np.ndarray] | None = None, start: Sequence[float] | None = None):
    """Least squares over [severity] + nuisance factors; returns (x, residuals, jacobian)."""
    from scipy.optimize import least_squares
    spec = FAULTS[fault] if fault else None
    lo = ([spec.lo] if spec else []) + [FREE_BOUNDS[0]] * len(free)
    hi = ([spec.hi] if spec else []) + [FREE_BOUNDS[1]] * len(free)

    def unpack(x):
        sev = float(x[0]) if spec else None
        return sev, {k: float(v) for k, v in zip(free, x[1:] if spec else x)}

    def fun(x):
        sev, fr = unpack(x)
        return problem.residuals(problem.run(problem.params(fault, sev, fr)), recorded)

    if start is None:
        start = [1.0] * len(free)
        if spec:                     # the best of a coarse grid, nuisance at design values
            grid = _start_grid(fault)
            costs = [float(np.sum(fun([g] + start) ** 2)) for g in grid]
            start = [grid[int(np.argmin(costs))]] + start
    if not lo:                                   # healthy, nothing free: no fit to make
        return np.zeros(0), fun(np.zeros(0)), np.zeros((len(problem.rows) * 3, 0))
    scale = [(h - l) / 10.0 for l, h in zip(lo, hi)]
    x0 = np.clip(np.asarray(start, dtype=float), lo, hi)
    sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, diff_step=1e-3,
                        method='trf', xtol=1e-6, ftol=1e-8, max_nfev=60)
    return sol.x, sol.fun, sol.jac


def diagnose(signals: Mapping[str, np.ndarray], design: EhaParams, *, control_period: float,
             model: str = 'SQ', faults: Sequence[str] = DIAGNOSABLE,
             window: tuple[float, float] | None = None, free: Sequence[str] = (),
             bootstrap: int = 0, seed: int = 0) -> Diagnosis:
    """Fit every hypothesis and rank them (see the module docstring).

    :param signals: the run's 1 ms rows (``read_bag(...).signals``, ``simulate(...).signals``)
    :param design: the parameters the run was meant to have (a bag's provenance)
    :param control_period: the ECU's sampling period of the run [s]
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
    problem = _Problem(signals, design, model, control_period, window)
    results = []
    for fault in [None, *faults]:
        x, res, jac = _fit(problem, fault, list(free))
        results.append((fault, x, res, jac))
    n = len(results[0][2])
    n_eff = _effective_n(results[0][2], len(SIGNALS))
    candidates = []
    for fault, x, res, jac in results:
        rss = float(np.dot(res, res))
        k = len(x)
        score = n_eff * math.log(max(rss, 1e-300) / n) + k * math.log(n_eff)
        sev = float(x[0]) if fault else None
        interval = None
        if fault:
            interval = _jacobian_interval(fault, x, res, jac, n, n_eff)
        freev = dict(zip(free, (x[1:] if fault else x).tolist()))
        fitted = problem.run(problem.params(fault, sev, freev))
        candidates.append(Candidate(fault or HEALTHY, sev, interval, score, rss, freev,
                                    fitted or {}))
    candidates.sort(key=lambda c: c.score)
    # the verdict: the best-scoring hypothesis that is healthy or a fault of a size worth
    # reporting; a fault fitted below DETECTABLE of its alarm severity is the model's own
    # mismatch (a healthy HD unit fits a 2 % null bias under SQ), so it yields to healthy
    best = next(c for c in candidates if c.fault == HEALTHY or _detectable(c))
    candidates.remove(best)
    candidates.insert(0, best)
    if bootstrap and best.fault != HEALTHY:
        best.interval = _bootstrap_interval(problem, best, list(free), bootstrap, seed)
    return Diagnosis(model=model, window=problem.window, candidates=candidates, n_eff=n_eff,
                     evaluations=problem.evaluations, recorded=dict(problem.recorded,
                                                                    t=problem.t))


def _detectable(c: Candidate) -> bool:
    f = FAULTS[c.fault]
    healthy = 1.0 if f.kind == 'scale' else 0.0
    return abs(c.severity - healthy) >= DETECTABLE * abs(f.demo - healthy)


def _jacobian_interval(fault, x, res, jac, n, n_eff) -> tuple[float, float]:
    spec = FAULTS[fault]
    k = len(x)
    s2 = float(np.dot(res, res)) / max(n - k, 1)
    jtj = jac.T @ jac
    try:
        cov = np.linalg.pinv(jtj) * s2 * (n / n_eff)
        half = 1.96 * math.sqrt(max(float(cov[0, 0]), 0.0))
    except np.linalg.LinAlgError:
        half = math.inf
    if not math.isfinite(half):
        return (spec.lo, spec.hi)
    return (max(spec.lo, float(x[0]) - half), min(spec.hi, float(x[0]) + half))


def _bootstrap_interval(problem: _Problem, best: Candidate, free: list[str], n: int,
                        seed: int) -> tuple[float, float]:
    """Percentile interval of ``n`` refits to fitted + moving blocks of the residuals."""
    rng = np.random.default_rng(seed)
    m = len(problem.rows)
    resid = {s: problem.recorded[s] - best.fitted[s] for s in SIGNALS}
    sev = []
    start = [best.severity] + [best.free[k] for k in free]
    for _ in range(n):
        starts = rng.integers(0, max(1, m - BLOCK_ROWS), size=-(-m // BLOCK_ROWS))
        idx = np.concatenate([np.arange(a, a + BLOCK_ROWS) for a in starts])[:m] % m
        synthetic = {s: best.fitted[s] + resid[s][idx] for s in SIGNALS}
        x, _, _ = _fit(problem, best.fault, free, synthetic, start)
        sev.append(float(x[0]))
    lo, hi = np.percentile(sev, [2.5, 97.5])
    return (float(lo), float(hi))


__all__ = ['diagnose', 'Diagnosis', 'Candidate', 'DIAGNOSABLE', 'HEALTHY']
