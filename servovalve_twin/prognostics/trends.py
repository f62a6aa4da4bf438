"""The trend models of prognosis (:mod:`.prognosis`): each fitted to a fault's severities
over flight cycles, weighted by the readings' own intervals, and weighed against the others.

Trend models (:data:`TRENDS`), with ``h`` the fault's healthy severity
(:attr:`~..physics.faults.FaultSpec.healthy`: 1 for a multiplier, 0 for a fraction):

- ``constant``, ``s(n) = c``: no degradation;
- ``linear``, ``s(n) = a + b*n``;
- ``quadratic``, ``s(n) = a + b*x + c*x^2`` (``x`` the cycles since the last flight): the
  polynomial degradation path (Lu & Meeker), for growth that speeds up or slows down by a law
  none of the others is (a power law ``(n/N)^1.5`` read as a line gave RULs 2.5 x too long);
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
residuals (the readings' own intervals), scaled by the overdispersion ``c = max(1, chi2/dof)``
of the moving fit with the least scatter per degree of freedom (QAICc: the diagnosed intervals
may be too narrow, and then every flexible model looks better than it is; the small-sample
term counts the flights), with a prior from the fault's physics (:data:`LAW`: a leak or a
clearance accelerates, everything else grows at a steady rate; :data:`LAW_ODDS` to 1 for the
models of that law). The posterior weights ``w_m = p_m exp(-QAICc_m/2) / sum``, kept as
logarithms (a weight below what a float holds is not 0 among the moving models), mix the
models in the RUL.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from ..physics.faults import FAULTS

#: the smallest relative uncertainty a diagnosed severity is given in a trend (of its
#: distance from healthy)
REL_SIGMA_FLOOR = 0.03
#: ... and the smallest absolute one, as a fraction of the span from healthy to the alarm value
ABS_SIGMA_FLOOR = 0.01
#: Huber's constant: residuals beyond this many robust standard deviations are down-weighted
HUBER_K = 2.5
#: ... and flights beyond this many are left out (a Gaussian error that large: 6e-7)
REJECT_Z = 5.0
#: how each fault's severity grows with wear, from its physics: a leak or a clearance grows
#: faster the larger it is (the flow through a gap goes with its cube; a worn land wears the
#: faster), a friction, a gain or a flow loss at a steady rate (seal and magnet wear per cycle)
LAW = {'leakage_growth': 'accelerating', 'clearance_growth': 'accelerating'}
#: the trend models of each law
LAW_MODELS = {'accelerating': ('quadratic', 'exponential', 'offset exponential'),
              'linear': ('linear',)}
#: prior odds of a model of the fault's law against any other trend model
LAW_ODDS = 3.0
TRENDS = ('constant', 'linear', 'quadratic', 'exponential', 'offset exponential', 'step')
#: the models that extrapolate to a crossing
MOVING = ('linear', 'quadratic', 'exponential', 'offset exponential')


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
    log_weight: float = 0.0         # its logarithm (the weight may underflow; this not)

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
        if self.kind == 'quadratic':
            x = n - self.n_ref
            return c[0] + c[1] * x + c[2] * x * x
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
            elif self.kind == 'quadratic':
                n = self.n_ref + _first_root(coef[:, 0] - threshold, coef[:, 1], coef[:, 2],
                                             sign)
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


def _first_root(a, b, c, sign):
    """Per row, the smallest x > 0 at which ``sign * (a + b x + c x^2)`` rises to 0 (``sign``
    1: a severity growing to its threshold, -1: falling to it); -inf where it is there already
    (``sign * a >= 0``), inf where it never is."""
    a, b, c = sign * a, sign * b, sign * c
    disc = b * b - 4 * a * c
    root = np.sqrt(np.maximum(disc, 0.0))
    # the two roots, computed without cancellation: q/c and a/q
    q = -0.5 * (b + np.copysign(root, b))
    r1 = np.divide(q, c, out=np.full_like(q, np.inf), where=c != 0)
    r2 = np.divide(a, q, out=np.full_like(q, np.inf), where=q != 0)
    lin = np.divide(-a, b, out=np.full_like(a, np.inf), where=b != 0)
    r1 = np.where(c == 0, lin, r1)
    r2 = np.where(c == 0, lin, r2)
    r1 = np.where((disc >= 0) & (r1 > 0), r1, np.inf)
    r2 = np.where((disc >= 0) & (r2 > 0), r2, np.inf)
    return np.where(a >= 0, -np.inf, np.minimum(r1, r2))


def law_prior(fault: str) -> dict[str, float]:
    """Prior probabilities of the trend models for ``fault`` (:data:`LAW`, default linear):
    :data:`LAW_ODDS` to 1 for each model of its law against each other model."""
    own = LAW_MODELS[LAW.get(fault, 'linear')]
    raw = {k: (LAW_ODDS if k in own else 1.0) for k in TRENDS}
    total = sum(raw.values())
    return {k: v / total for k, v in raw.items()}


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


def _quadratic(n, s, w) -> Trend | None:
    """s = a + b x + c x^2, x the cycles since the last flight; None with fewer than four
    flights (no scatter left to judge it by)."""
    if len(n) < 4:
        return None
    n_ref = float(n[-1])
    x = n - n_ref
    X = np.column_stack([np.ones_like(x), x, x * x]) * w[:, None]
    coef, *_ = np.linalg.lstsq(X, s * w, rcond=None)
    res = X @ coef - s * w
    return Trend('quadratic', coef, np.linalg.pinv(X.T @ X), float(res @ res), n_ref=n_ref)


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
    apart = n[j] > n[i]                 # two diagnoses of one flight give no slope
    slope = float(np.median((s[j] - s[i])[apart] / (n[j] - n[i])[apart]))
    best = np.median(s - slope * n) + slope * n
    for k in range(2, len(n) - 1):
        levels = np.r_[np.full(k, np.median(s[:k])), np.full(len(n) - k, np.median(s[k:]))]
        if np.sum(np.abs(s - levels)) < np.sum(np.abs(s - best)):
            best = levels
    return best


def _weigh(n: np.ndarray, s: np.ndarray, sig: np.ndarray, fault: str) -> list[Trend]:
    w = 1.0 / sig
    h = FAULTS[fault].healthy
    fits = [_constant(n, s, w), _weighted_line(n, s, w), _quadratic(n, s, w),
            _exponential(n, s, w, 0.0, 'exponential'),
            _exponential(n, s, w, h, 'offset exponential') if h != 0 else None, _step(n, s, w)]
    fits = [f for f in fits if f is not None]
    m = len(n)
    # overdispersion from the moving fit that leaves the least scatter per degree of freedom:
    # the scatter the intervals do not count
    c = max(1.0, min(f.chi2 / max(m - f.k, 1) for f in fits if f.kind in MOVING))
    scores = []
    for f in fits:
        f.cov = f.cov * c
        k = f.k + 1                                 # the overdispersion is estimated too
        corr = 2 * k * (k + 1) / (m - k - 1) if m - k - 1 > 0 else math.inf
        scores.append((f.chi2 / c + 2 * k + corr, f.chi2 / c + 2 * k))
    # too few flights for the small-sample correction of every model: plain QAIC for all (a
    # model without the correction would otherwise take the weight from those with it)
    scores = [a for a, _ in scores] if all(math.isfinite(a) for a, _ in scores) else [
        b for _, b in scores]
    prior = law_prior(fault)
    logw = np.array([-0.5 * x + math.log(prior[f.kind]) if math.isfinite(x) else -math.inf
                     for f, x in zip(fits, scores)])
    logw -= np.logaddexp.reduce(logw)
    for f, lw in zip(fits, logw):
        f.log_weight = float(lw)
        f.weight = float(math.exp(lw))
    fits.sort(key=lambda f: -f.log_weight)
    return fits


__all__ = ['fit_trends', 'law_prior', 'Trend', 'TRENDS', 'MOVING', 'LAW', 'LAW_MODELS',
           'LAW_ODDS', 'REL_SIGMA_FLOOR', 'ABS_SIGMA_FLOOR', 'HUBER_K', 'REJECT_Z']
