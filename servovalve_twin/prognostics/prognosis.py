"""Prognosis across flights: a fault's severity, diagnosed flight after flight, trended and
extrapolated to the threshold at which the unit must be fixed -- the remaining useful life
(RUL) in flight cycles, with its uncertainty -- or the statement that there is nothing to
extrapolate.

The trends and their weights: :mod:`.trends`.

Verdicts (``status``):

- ``past threshold``: the last flight's stated interval lies wholly beyond the threshold:
  RUL 0, whatever the trend says (the diagnosis' intervals are calibrated; a reading whose
  interval only reaches the threshold gives a life interval that starts at 0);
- ``too few flights``: fewer than :data:`MIN_CYCLES` distinct flight cycles, and not past the
  threshold: no trend can be told, no RUL (null in the JSON);
- ``no degradation trend``: no significant motion toward the threshold -- the linear slope
  toward it is below :data:`TREND_Z` standard errors and the step model is not preferred --
  so no finite RUL is given (a trend fitted to noise extrapolates to anything);
- ``step change``: the step model is preferred (it has the largest weight); RUL 0 when the
  level after the step is beyond the threshold, else no finite RUL (no trend since the step);
- ``trend``: the RUL is the cycle at which the trend crosses the threshold, minus the last
  flight's; its distribution comes from Monte Carlo over each trending model's parameter
  covariance, mixed by the models' weights (a draw that never reaches the threshold counts as
  infinite life); median, 5th and 95th percentiles: a 90 % interval that carries the flights'
  severity uncertainty, the trend's and the choice of model. The parameters are drawn from a
  normal, or a Student t where the scatter was estimated from the flights (``c > 1``).

Measured on seeded histories the method was not built on: doc/results/diagnosis.md, section
Prognosis (``bench/bench_prognosis.py``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS
from .trends import MOVING, Trend, fit_trends

#: a trend is significant when the linear slope toward the threshold exceeds this many
#: standard errors (one-sided 2.3 % of trend-free histories called a trend)
TREND_Z = 2.0
#: fewer distinct flight cycles than this: no trend is fitted ('too few flights')
MIN_CYCLES = 3


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


def _past(lo: float, hi: float, thr: float, sign: float) -> bool:
    """Whether the interval [lo, hi] lies wholly past the threshold."""
    return sign * ((lo if sign > 0 else hi) - thr) > 0


def _reaches(lo: float, hi: float, thr: float, sign: float) -> bool:
    """Whether the interval [lo, hi] reaches the threshold (the unit may be past it now)."""
    return sign * ((hi if sign > 0 else lo) - thr) >= 0


def _checked(history, fault, threshold):
    """The history as arrays (cycles, severities, stated sigmas, 95 % intervals), the
    threshold and model_sigma; every bad input refused in one line."""
    if fault not in FAULTS:
        raise TwinError(f'unknown fault {fault!r}; expected one of {sorted(FAULTS)}')
    if len(history) < 1:
        raise TwinError('a prognosis needs at least one diagnosed flight, got none')
    spec = FAULTS[fault]
    thr = spec.demo if threshold is None else float(threshold)
    if not (spec.lo <= thr <= spec.hi) or thr == spec.healthy:
        raise TwinError(f'threshold {thr!r} {spec.unit} must be a severity of {fault} in '
                        f'[{spec.lo:g}, {spec.hi:g}] other than the healthy {spec.healthy:g}')
    try:
        cycles = np.array([float(h['cycles']) for h in history])
        sev = np.array([float(h['severity']) for h in history])
        ivs = np.array([[float(x) for x in h['interval']] if h.get('interval') is not None
                        else [math.nan, math.nan] for h in history])
        model_sigma = float(np.median([float(h.get('model_sigma') or 0.0) for h in history]))
    except (KeyError, TypeError, ValueError):
        raise TwinError('each flight must hold numbers cycles and severity, and may hold '
                        'interval [lo, hi] and model_sigma') from None
    if not (np.all(np.isfinite(cycles)) and np.all(np.isfinite(sev))):
        raise TwinError('flight cycles and severities must be finite numbers')
    if np.any(np.diff(cycles) < 0):
        raise TwinError(f'flight cycles must not decrease, got {cycles.tolist()}')
    if not (math.isfinite(model_sigma) and model_sigma >= 0):
        raise TwinError('model_sigma of a flight must be a finite number >= 0')
    known = np.all(np.isfinite(ivs), axis=1)
    if np.any(ivs[known, 1] < ivs[known, 0]):
        raise TwinError('a flight\'s interval must be [lo, hi] with lo <= hi')
    sig = np.where(known, np.maximum((ivs[:, 1] - ivs[:, 0]) / (2 * 1.96), 1e-12),
                   abs(thr - spec.healthy))
    ivs = np.where(known[:, None], ivs, np.column_stack([sev, sev]))
    return cycles, sev, sig, ivs, thr, model_sigma


def _draw_life(trends, cycles, thr, up, c, model_sigma, draws, rng, healthy):
    """Monte-Carlo RUL samples over the moving trends, each drawn as often as its weight among
    them (log-space weights: never a division by a sum that underflowed)."""
    moving = [t for t in trends if t.kind in MOVING]
    logw = np.array([t.log_weight for t in moving])
    share = (np.exp(logw - logw[np.isfinite(logw)].max()) if np.isfinite(logw).any()
             else np.ones(len(moving)))
    share /= share.sum()
    counts = np.floor(share * draws + 0.5).astype(int)
    parts = []
    for t, k in zip(moving, counts):
        if k == 0:
            continue
        z = rng.multivariate_normal(np.zeros(len(t.coef)), t.cov, size=k, check_valid='ignore')
        if c > 1.0:
            # the scatter was estimated from the flights (not taken from their intervals):
            # Student-t draws, a normal times sqrt(dof/chi2(dof)), dof the flights left
            dof = max(len(cycles) - t.k, 1)
            z = z * np.sqrt(dof / rng.chisquare(dof, size=k))[:, None]
        coef = t.coef + z
        # the diagnoses' common model-form error: every flight read (1 + beta) times its
        # true distance from healthy, so the truth crosses where the reading crosses
        # h + (1 + beta)*(threshold - h)
        beta = rng.normal(0.0, model_sigma, size=k) if model_sigma > 0 else 0.0
        thr_k = healthy + (thr - healthy) * (1.0 + beta)
        parts.append(t.crossing(thr_k, coef, up) - cycles[-1])
    return np.maximum(np.concatenate(parts), 0.0), max(moving, key=lambda t: t.log_weight)


def prognose(history: Sequence[dict[str, Any]], fault: str, threshold: float | None = None,
             *, draws: int = 4000, seed: int = 0) -> Prognosis:
    """RUL from ``history``: ``[{'cycles', 'severity', 'interval'}, ...]`` in flight order
    (cycles non-decreasing: two diagnoses of one flight may share its cycle), ``interval`` a
    95 % interval of the severity (see the module docstring). An entry may carry
    ``model_sigma``: the relative standard deviation of the diagnosis' model-form error
    (common to every flight of a unit, so it is not averaged away by the trend); the RUL
    interval then carries it. Any history of one flight or more gets an answer."""
    cycles, sev, sig, ivs, thr, model_sigma = _checked(history, fault, threshold)
    spec = FAULTS[fault]
    up = thr > spec.healthy                       # degradation moves away from healthy
    sign = 1.0 if up else -1.0
    zero = dict(median=0.0, p05=0.0, p95=0.0)
    inf = dict(median=math.inf, p05=math.inf, p95=math.inf)
    past = _past(*ivs[-1], thr, sign)
    rng = np.random.default_rng(seed)
    if len(np.unique(cycles)) < MIN_CYCLES:
        # no trend can be told from fewer distinct flights: past or not, nothing more
        only = Trend('constant', np.array([sev[-1]]), np.array([[sig[-1] ** 2]]), 0.0,
                     log_weight=0.0)
        status, rul = ('past threshold', zero) if past else ('too few flights', dict(
            median=math.nan, p05=0.0 if _reaches(*ivs[-1], thr, sign) else math.nan,
            p95=math.nan))
        return Prognosis(fault, thr, status, only, [only], [dict(h) for h in history], rul,
                         np.zeros(1) if past else np.full(1, np.nan), math.nan)
    trends, c = fit_trends(cycles, sev, sig, fault)
    linear = next(t for t in trends if t.kind == 'linear')
    slope_z = float(sign * linear.coef[1] / math.sqrt(max(linear.cov[1, 1], 1e-300)))
    best = trends[0]
    if past:
        # the last flight's stated interval lies wholly past the threshold: whatever the
        # trend says, the unit is there now
        status, rul, out = 'past threshold', zero, np.zeros(1)
    elif best.kind == 'step' and sign * (best.coef[1] - best.coef[0]) > 0:
        status = 'step change'
        beyond = sign * (best.coef[1] - thr) >= 0
        rul, out = (zero, np.zeros(1)) if beyond else (inf, np.full(1, np.inf))
    elif slope_z < TREND_Z:
        status, rul, out = 'no degradation trend', inf, np.full(1, np.inf)
    else:
        status = 'trend'
        out, best = _draw_life(trends, cycles, thr, up, c, model_sigma, draws, rng,
                               spec.healthy)
        # 'nearest': no arithmetic between infinite lives (inf - inf is nan)
        p05, p50, p95 = np.percentile(out, [5, 50, 95], method='nearest')
        rul = dict(median=float(p50), p05=float(p05), p95=float(p95))
    if status != 'past threshold' and _reaches(*ivs[-1], thr, sign):
        # the last reading's interval reaches the threshold: the unit may be past it now, so
        # its life's interval starts at 0
        rul = dict(rul, p05=0.0)
    return Prognosis(fault, thr, status, best, trends, [dict(h) for h in history], rul, out,
                     slope_z)


__all__ = ['prognose', 'Prognosis', 'TREND_Z', 'MIN_CYCLES']
