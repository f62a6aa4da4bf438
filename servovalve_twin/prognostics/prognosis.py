"""Prognosis across flights: a fault's severity, diagnosed flight after flight, trended and
extrapolated to the threshold at which the unit must be fixed -- the remaining useful life
(RUL) in flight cycles, with its uncertainty -- or the statement that there is nothing to
extrapolate.

Trend models (:data:`TRENDS`), with ``h`` the fault's healthy severity
(:attr:`~..physics.faults.FaultSpec.healthy`: 1 for a multiplier, 0 for a fraction):

- ``constant``, ``s(n) = c``: no degradation;
- ``linear``, ``s(n) = a + b*n``;
- ``exponential``, ``s(n) = a*exp(b*n)``: a severity that grows in proportion to itself (a
  leakage multiplier 1, 1.1, 1.21, ...);
- ``offset exponential``, ``s(n) = h + a*exp(b*n)``: a departure from healthy that grows in
  proportion to itself (a leak 1 + 0.4*e^(n/30)); for a fraction (h = 0) it is the exponential.
  Both are fitted as written, by weighted nonlinear least squares started from the log-linear
  fit of s - h;
- ``step``, ``s(n) = c1`` before a flight ``n0`` and ``c2`` from it on: a sudden change (a
  part that broke, a repair), ``n0`` the best split.

Weights. Each severity counts with its diagnosed interval (sigma = half-width/1.96), but never
tighter than :data:`REL_SIGMA_FLOOR` of its distance from healthy plus :data:`ABS_SIGMA_FLOOR`
of the span from healthy to the alarm severity: a severity diagnosed at 2e-10 is not known to
1e-11, and a trend weighted by such a point follows it alone.

Model choice. The models are compared by the small-sample Akaike criterion of their weighted
residuals, scaled by the overdispersion ``c = max(1, chi2/dof)`` of the best two-parameter fit
(QAICc: the diagnosed intervals may be too narrow, and then every flexible model looks better
than it is); the Akaike weights ``w_m = exp(-D_m/2)/sum`` mix the models in the RUL.

Verdicts (``status``):

- ``past threshold``: the last flight's severity (its whole interval) is already beyond the
  threshold: RUL 0;
- ``no degradation trend``: no significant motion toward the threshold -- the linear slope
  toward it is below :data:`TREND_Z` standard errors and the step model is not preferred --
  so no finite RUL is given (a trend fitted to noise extrapolates to anything);
- ``step change``: the step model is preferred (it has the largest weight); RUL 0 when the
  level after the step is beyond the threshold, else no finite RUL (no trend since the step);
- ``trend``: the RUL is the cycle at which the trend crosses the threshold, minus the last
  flight's; its distribution comes from Monte Carlo over each trending model's parameter
  covariance, mixed by the models' weights (a draw that never reaches the threshold counts as
  infinite life); median, 5th and 95th percentiles: a 90 % interval that carries the flights'
  severity uncertainty, the trend's and the choice of model.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS

#: the smallest relative uncertainty a diagnosed severity is given in a trend (of its
#: distance from healthy)
REL_SIGMA_FLOOR = 0.03
#: ... and the smallest absolute one, as a fraction of the span from healthy to the alarm value
ABS_SIGMA_FLOOR = 0.01
#: a trend is significant when the linear slope toward the threshold exceeds this many
#: standard errors (one-sided 2.3 % of trend-free histories called a trend)
TREND_Z = 2.0
#: Huber's constant: residuals beyond this many robust standard deviations are down-weighted
HUBER_K = 2.5
#: ... and flights beyond this many are left out (a Gaussian error that large: 6e-7)
REJECT_Z = 5.0
TRENDS = ('constant', 'linear', 'exponential', 'offset exponential', 'step')
#: the models that extrapolate to a crossing
MOVING = ('linear', 'exponential', 'offset exponential')


@dataclasses.dataclass
class Trend:
    """One fitted trend model: ``coef`` and ``cov`` of its free parameters (the step's split
    ``n0`` is held), ``chi2`` its weighted residual sum of squares."""

    kind: str
    coef: np.ndarray
    cov: np.ndarray
    chi2: float
    h: float = 0.0                  # the exponential's offset (the healthy severity)
    n_ref: float = 0.0              # the exponential's time origin (the last flight)
    n0: float = math.nan            # the step's first flight after the change
    weight: float = 1.0             # Akaike weight among the models

    @property
    def k(self) -> int:
        """Parameters fitted (the step's split counts)."""
        return len(self.coef) + (1 if self.kind == 'step' else 0)

    def __call__(self, n, coef=None):
        c = self.coef if coef is None else coef
        n = np.asarray(n, dtype=float)
        if self.kind == 'constant':
            return c[0] + 0.0 * n
        if self.kind == 'linear':
            return c[0] + c[1] * n
        if self.kind.endswith('exponential'):
            return self.h + c[0] * np.exp(c[1] * (n - self.n_ref))
        return np.where(n < self.n0, c[0], c[1])

    def crossing(self, threshold, coef: np.ndarray, up: bool) -> np.ndarray:
        """Cycle at which the trend reaches ``threshold`` (from below when ``up``; a number,
        or one per row) per row of ``coef``; inf where it never does, -inf where it is beyond
        it already."""
        a, b = coef[:, 0], coef[:, -1]
        sign = 1.0 if up else -1.0
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            if self.kind == 'linear':
                n = (threshold - a) / b
                n = np.where(sign * b > 0, n, np.where(sign * (a - threshold) >= 0, -np.inf,
                                                       np.inf))
            elif self.kind.endswith('exponential'):
                ratio = (threshold - self.h) / a
                # a*e^(b t) grows away from h when b > 0: it reaches the threshold if that lies
                # on a's side of h
                n = self.n_ref + np.log(ratio) / b
                n = np.where((ratio > 0) & (b > 0), n, np.inf)
            elif self.kind == 'step':
                n = np.where(sign * (b - threshold) >= 0, -np.inf, np.inf)
            else:
                n = np.full(len(coef), np.inf)
        return np.where(np.isnan(n), np.inf, n)


def _sigmas(severities: np.ndarray, sigmas: np.ndarray, fault: str) -> np.ndarray:
    spec = FAULTS[fault]
    span = abs(spec.demo - spec.healthy)
    floor = REL_SIGMA_FLOOR * np.abs(severities - spec.healthy) + ABS_SIGMA_FLOOR * span
    return np.maximum(sigmas, floor)


def _weighted_line(n, y, w, kind='linear') -> Trend:
    X = np.column_stack([np.ones_like(n), n]) * w[:, None]
    coef, *_ = np.linalg.lstsq(X, y * w, rcond=None)
    res = X @ coef - y * w
    return Trend(kind, coef, np.linalg.pinv(X.T @ X), float(res @ res))


def _constant(n, s, w) -> Trend:
    c = float(np.sum(w ** 2 * s) / np.sum(w ** 2))
    return Trend('constant', np.array([c]), np.array([[1.0 / np.sum(w ** 2)]]),
                 float(np.sum((w * (s - c)) ** 2)))


def _exponential(n, s, w, h, kind) -> Trend | None:
    """s = h + a*exp(b*(n - n_ref)) by weighted least squares; None where fewer than two
    flights lie on the departure's side of h (nothing to follow)."""
    from scipy.optimize import least_squares
    d = s - h
    sign = 1.0 if np.sum(w ** 2 * d) >= 0 else -1.0
    n_ref = float(n[-1])
    # the start: a line through ln|s - h| of the points on the departure's side
    ok = sign * d > 0
    if ok.sum() < 2:
        return None
    line = _weighted_line(n[ok] - n_ref, np.log(sign * d[ok]), w[ok] * sign * d[ok])
    x0 = np.array([sign * math.exp(line.coef[0]), line.coef[1]])

    def fun(x):
        with np.errstate(over='ignore'):
            return w * (h + x[0] * np.exp(np.clip(x[1] * (n - n_ref), -700, 700)) - s)

    try:
        sol = least_squares(fun, x0, method='lm', xtol=1e-12, ftol=1e-12, max_nfev=400)
    except ValueError:
        return None
    if not np.all(np.isfinite(sol.x)):
        return None
    J = sol.jac
    return Trend(kind, sol.x, np.linalg.pinv(J.T @ J), float(sol.fun @ sol.fun), h=h,
                 n_ref=n_ref)


def _step(n, s, w) -> Trend | None:
    """The best split into two constant levels, at least two flights on each side."""
    best = None
    for j in range(2, len(n) - 1):
        a, b = _constant(n[:j], s[:j], w[:j]), _constant(n[j:], s[j:], w[j:])
        chi2 = a.chi2 + b.chi2
        if best is None or chi2 < best.chi2:
            best = Trend('step', np.array([a.coef[0], b.coef[0]]),
                         np.diag([a.cov[0, 0], b.cov[0, 0]]), chi2, n0=float(n[j]))
    return best


def fit_trends(cycles: Sequence[float], severities: Sequence[float],
               sigmas: Sequence[float], fault: str) -> tuple[list[Trend], float]:
    """Every trend model fitted, Akaike weights set, best first; and the overdispersion.
    A flight whose severity lies more than :data:`HUBER_K` robust standard deviations from the
    best model is down-weighted (Huber's M-estimate, by reweighting), one beyond
    :data:`REJECT_Z` left out: one misdiagnosed flight must not set the trend."""
    n = np.asarray(cycles, dtype=float)
    s = np.asarray(severities, dtype=float)
    sig0 = _sigmas(s, np.asarray(sigmas, dtype=float), fault)
    fitted = _robust_start(n, s)
    for _ in range(3):
        r = np.abs(s - fitted) / sig0
        z = r / max(1.0, 1.4826 * float(np.median(r)))
        # Huber's weights, and none at all beyond REJECT_Z (a flight that far off is misread)
        inflate = np.where(z > REJECT_Z, 1e6, np.maximum(1.0, z / HUBER_K))
        fits = _weigh(n, s, sig0 * inflate, fault)
        fitted = fits[0](n)
    return fits, max(1.0, fits[0].chi2 / max(len(n) - fits[0].k, 1))


def _robust_start(n: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The first fit, from which outlying flights are judged: the Theil-Sen line (the median
    of the pairwise slopes), which a misread flight cannot pull -- least squares can, so far
    that its residual looks ordinary -- or, where it leaves less absolute residual, two levels
    (medians) split at the best flight with at least two flights on each side: a step is no
    outlier (four flights past a step, judged from a line through the eight before, were left
    out as misread and the unit given no trend)."""
    i, j = np.triu_indices(len(n), 1)
    slope = float(np.median((s[j] - s[i]) / (n[j] - n[i])))
    best = np.median(s - slope * n) + slope * n
    for k in range(2, len(n) - 1):
        levels = np.r_[np.full(k, np.median(s[:k])), np.full(len(n) - k, np.median(s[k:]))]
        if np.sum(np.abs(s - levels)) < np.sum(np.abs(s - best)):
            best = levels
    return best


def _weigh(n: np.ndarray, s: np.ndarray, sig: np.ndarray, fault: str) -> list[Trend]:
    w = 1.0 / sig
    h = FAULTS[fault].healthy
    fits = [_constant(n, s, w), _weighted_line(n, s, w), _exponential(n, s, w, 0.0, 'exponential'),
            _exponential(n, s, w, h, 'offset exponential') if h != 0 else None, _step(n, s, w)]
    fits = [f for f in fits if f is not None]
    m = len(n)
    # overdispersion from the best two-parameter fit: the scatter the intervals do not count
    two = [f for f in fits if f.kind in MOVING]
    c = max(1.0, min(f.chi2 for f in two) / max(m - 2, 1))
    scores = []
    for f in fits:
        f.cov = f.cov * c
        k = f.k + 1                                 # the overdispersion is estimated too
        corr = 2 * k * (k + 1) / (m - k - 1) if m - k - 1 > 0 else math.inf
        scores.append((f.chi2 / c + 2 * k + corr, f.chi2 / c + 2 * k))
    # too few flights for the small-sample correction of any model: plain QAIC
    scores = [a for a, _ in scores] if any(math.isfinite(a) for a, _ in scores) else [
        b for _, b in scores]
    best = min(scores)
    raw = [math.exp(-0.5 * (x - best)) if math.isfinite(x) else 0.0 for x in scores]
    for f, r in zip(fits, raw):
        f.weight = r / sum(raw)
    fits.sort(key=lambda f: -f.weight)
    return fits


@dataclasses.dataclass
class Prognosis:
    fault: str
    threshold: float
    status: str                     # 'trend' | 'no degradation trend' | 'past threshold' | ...
    trend: Trend                    # the trend model of the verdict (best weight)
    trends: list[Trend]
    history: list[dict[str, Any]]
    rul: dict[str, float]
    draws: np.ndarray
    slope_z: float                  # the linear slope toward the threshold, in standard errors

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``prognose --json``: RULs of inf (no finite life) as null."""
        return dict(fault=self.fault, threshold=self.threshold, status=self.status,
                    rul_cycles={k: (None if not math.isfinite(v) else v)
                                for k, v in self.rul.items()},
                    trend=self.trend.kind,
                    trend_weights={t.kind: t.weight for t in self.trends},
                    slope_z=self.slope_z,
                    step_at=None if self.trend.kind != 'step' else self.trend.n0,
                    history=self.history)


def prognose(history: Sequence[dict[str, Any]], fault: str, threshold: float | None = None,
             *, draws: int = 4000, seed: int = 0) -> Prognosis:
    """RUL from ``history``: ``[{'cycles', 'severity', 'interval'}, ...]`` in flight order,
    ``interval`` a 95 % interval of the severity (see the module docstring). An entry may
    carry ``model_sigma``: the relative standard deviation of the diagnosis' model-form error
    (common to every flight of a unit, so it is not averaged away by the trend); the RUL
    interval then carries it."""
    if fault not in FAULTS:
        raise TwinError(f'unknown fault {fault!r}; expected one of {sorted(FAULTS)}')
    if len(history) < 3:
        raise TwinError(f'a trend needs at least three flights, got {len(history)}')
    cycles = [float(h['cycles']) for h in history]
    sev = [float(h['severity']) for h in history]
    if not all(math.isfinite(x) for x in cycles + sev):
        raise TwinError('flight cycles and severities must be finite numbers')
    if any(b <= a for a, b in zip(cycles, cycles[1:])):
        raise TwinError(f'flight cycles must increase, got {cycles}')
    spec = FAULTS[fault]
    thr = spec.demo if threshold is None else float(threshold)
    if not math.isfinite(thr) or thr == spec.healthy:
        raise TwinError(f'threshold {thr!r} must be a finite severity other than the healthy '
                        f'{spec.healthy:g}')
    up = thr > spec.healthy                       # degradation moves away from healthy
    sign = 1.0 if up else -1.0
    model_sigma = float(np.median([float(h.get('model_sigma') or 0.0) for h in history]))
    if not (math.isfinite(model_sigma) and model_sigma >= 0):
        raise TwinError('model_sigma of a flight must be a finite number >= 0')
    sig = [max((h['interval'][1] - h['interval'][0]) / (2 * 1.96), 1e-12)
           if h.get('interval') else abs(thr - spec.healthy) for h in history]
    trends, c = fit_trends(cycles, sev, sig, fault)
    linear = next(t for t in trends if t.kind == 'linear')
    slope_z = float(sign * linear.coef[1] / math.sqrt(max(linear.cov[1, 1], 1e-300)))
    best = trends[0]
    # the last flight is past the threshold when its 95 % interval is -- widened by the
    # scatter the flights show beyond their intervals (a reading 20 % off with a 2 % interval
    # would otherwise end a unit's life early)
    sig_last = float(_sigmas(np.array(sev[-1:]), np.array(sig[-1:]), fault)[0])
    low_end = sev[-1] - sign * 1.96 * sig_last * math.sqrt(c)
    rng = np.random.default_rng(seed)
    inf = dict(median=math.inf, p05=math.inf, p95=math.inf)
    if sign * (low_end - thr) >= 0:
        status, rul, out = 'past threshold', dict(median=0.0, p05=0.0, p95=0.0), np.zeros(1)
    elif best.kind == 'step' and sign * (best.coef[1] - best.coef[0]) > 0:
        status = 'step change'
        beyond = sign * (best.coef[1] - thr) >= 0
        rul = dict(median=0.0, p05=0.0, p95=0.0) if beyond else inf
        out = np.zeros(1) if beyond else np.full(1, np.inf)
    elif slope_z < TREND_Z:
        status, rul, out = 'no degradation trend', inf, np.full(1, np.inf)
    else:
        status = 'trend'
        moving = [t for t in trends if t.kind in MOVING]
        total = sum(t.weight for t in moving)
        parts = []
        for t in moving:
            k = int(round(draws * t.weight / total))
            if k == 0:
                continue
            # Student-t draws (the scatter was estimated from few flights): a normal times
            # sqrt(dof/chi2(dof)), dof the flights left after the trend's parameters
            dof = max(len(cycles) - t.k, 1)
            z = rng.multivariate_normal(np.zeros(len(t.coef)), t.cov, size=k,
                                        check_valid='ignore')
            coef = t.coef + z * np.sqrt(dof / rng.chisquare(dof, size=k))[:, None]
            # the diagnoses' common model-form error: every flight read (1 + beta) times its
            # true distance from healthy, so the truth crosses where the reading crosses
            # h + (1 + beta)*(threshold - h)
            beta = rng.normal(0.0, model_sigma, size=k) if model_sigma > 0 else 0.0
            thr_k = spec.healthy + (thr - spec.healthy) * (1.0 + beta)
            parts.append(t.crossing(thr_k, coef, up) - cycles[-1])
        out = np.maximum(np.concatenate(parts), 0.0)
        # 'nearest': no arithmetic between infinite lives (inf - inf is nan)
        p05, p50, p95 = np.percentile(out, [5, 50, 95], method='nearest')
        rul = dict(median=float(p50), p05=float(p05), p95=float(p95))
        best = max(moving, key=lambda t: t.weight)
    return Prognosis(fault, thr, status, best, trends, [dict(h) for h in history], rul, out,
                     slope_z)


__all__ = ['prognose', 'Prognosis', 'fit_trends', 'Trend', 'TRENDS']
