"""Prognosis across flights: a fault's severity, diagnosed flight after flight, trended and
extrapolated to the threshold at which the unit must be fixed -- the remaining useful life
(RUL) in flight cycles, with its uncertainty.

Trends (both two-parameter, chosen by the weighted residual sum of squares):

- linear, ``s(n) = a + b*n``;
- exponential, ``s(n) = a*exp(b*n)``: degradation that grows in proportion to itself (a
  leakage multiplier 1, 1.1, 1.21, ...), fitted as a line to ln|s|.

Each severity is weighted by its diagnosed 95 % interval (sigma = half-width/1.96), but never
tighter than :data:`REL_SIGMA_FLOOR` of the severity: the intervals count the fit's noise, not
the model's bias (SQ reads HD's leakage a few per cent low), and a trend weighted by them
alone follows that bias. The RUL is
the cycle at which the trend crosses the threshold, minus the last flight's: its distribution
comes from Monte Carlo over the trend's parameter covariance (a trend that never reaches the
threshold in a draw counts as infinite life); median, 5th and 95th percentiles.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS


#: the smallest relative uncertainty a diagnosed severity is given in a trend
REL_SIGMA_FLOOR = 0.03


@dataclasses.dataclass
class Trend:
    kind: str                       # 'linear' | 'exponential'
    coef: np.ndarray                # (a, b)
    cov: np.ndarray                 # 2x2
    rss: float

    def __call__(self, n, coef=None):
        a, b = self.coef if coef is None else coef
        n = np.asarray(n, dtype=float)
        if self.kind == 'linear':
            return a + b * n
        return a * np.exp(b * n)

    def crossing(self, threshold: float, coef: np.ndarray, up: bool) -> np.ndarray:
        """Cycle at which the trend reaches ``threshold`` (from below when ``up``), per row
        of ``coef``; inf where it moves away from it."""
        a, b = coef[:, 0], coef[:, 1]
        with np.errstate(divide='ignore', invalid='ignore'):
            if self.kind == 'linear':
                n = (threshold - a) / b
                toward = (b > 0) if up else (b < 0)
            else:
                ratio = threshold / a
                n = np.log(ratio) / b
                # |s - h| grows with b > 0; it must grow toward a threshold on a's side
                toward = (ratio > 0) & (((b > 0) & (ratio > 1)) | ((b < 0) & (ratio < 1)))
        return np.where(toward & np.isfinite(n), n, np.inf)


def fit_trend(cycles: Sequence[float], severities: Sequence[float],
              sigmas: Sequence[float]) -> Trend:
    """The better of the linear and exponential trends (weighted least squares)."""
    n = np.asarray(cycles, dtype=float)
    s = np.asarray(severities, dtype=float)
    sig = np.maximum(np.asarray(sigmas, dtype=float), REL_SIGMA_FLOOR * np.abs(s))
    w = 1.0 / np.maximum(sig, 1e-12)
    trends = [_weighted_line(n, s, w, 'linear')]
    if np.all(s > 0) or np.all(s < 0):
        # ln|s| = ln|a| + b*n, sigma of the log = sigma/|s|
        sign = 1.0 if s[0] > 0 else -1.0
        t = _weighted_line(n, np.log(np.abs(s)), w * np.abs(s), 'exponential')
        a = sign * math.exp(t.coef[0])
        jac = np.array([[a, 0.0], [0.0, 1.0]])                  # d(a, b)/d(ln|a|, b)
        t.coef = np.array([a, t.coef[1]])
        t.cov = jac @ t.cov @ jac.T
        t.rss = float(np.sum((w * (t(n) - s)) ** 2))
        trends.append(t)
    return min(trends, key=lambda t: t.rss)


def _weighted_line(n, y, w, kind) -> Trend:
    X = np.column_stack([np.ones_like(n), n]) * w[:, None]
    coef, *_ = np.linalg.lstsq(X, y * w, rcond=None)
    res = X @ coef - y * w
    dof = max(len(n) - 2, 1)
    s2 = max(float(res @ res) / dof, 1.0)     # never tighter than the diagnosed intervals
    cov = np.linalg.pinv(X.T @ X) * s2
    return Trend(kind, coef, cov, float(res @ res))


@dataclasses.dataclass
class Prognosis:
    fault: str
    threshold: float
    trend: Trend
    history: list[dict[str, Any]]
    rul: dict[str, float]
    draws: np.ndarray

    def to_json(self) -> dict[str, Any]:
        """The issue's schema, exactly."""
        return dict(fault=self.fault, threshold=self.threshold,
                    rul_cycles={k: (None if not math.isfinite(v) else v)
                                for k, v in self.rul.items()},
                    trend=self.trend.kind, history=self.history)


def prognose(history: Sequence[dict[str, Any]], fault: str, threshold: float | None = None,
             *, draws: int = 4000, seed: int = 0) -> Prognosis:
    """RUL from ``history``: ``[{'cycles', 'severity', 'interval'}, ...]`` in flight order."""
    if fault not in FAULTS:
        raise TwinError(f'unknown fault {fault!r}; expected one of {sorted(FAULTS)}')
    if len(history) < 3:
        raise TwinError(f'a trend needs at least three flights, got {len(history)}')
    cycles = [float(h['cycles']) for h in history]
    if any(b <= a for a, b in zip(cycles, cycles[1:])):
        raise TwinError(f'flight cycles must increase, got {cycles}')
    thr = FAULTS[fault].demo if threshold is None else float(threshold)
    sev = [float(h['severity']) for h in history]
    sig = [max((h['interval'][1] - h['interval'][0]) / (2 * 1.96), 1e-9) if h.get('interval')
           else 1.0 for h in history]
    trend = fit_trend(cycles, sev, sig)
    rng = np.random.default_rng(seed)
    coef = rng.multivariate_normal(trend.coef, trend.cov, size=draws, check_valid='ignore')
    up = thr > sev[-1] if thr != sev[-1] else thr > sev[0]
    rul = np.maximum(trend.crossing(thr, coef, up) - cycles[-1], 0.0)
    p05, p50, p95 = np.percentile(rul, [5, 50, 95])
    return Prognosis(fault, thr, trend, [dict(h) for h in history],
                     dict(median=float(p50), p05=float(p05), p95=float(p95)), rul)


__all__ = ['prognose', 'Prognosis', 'fit_trend', 'Trend']
