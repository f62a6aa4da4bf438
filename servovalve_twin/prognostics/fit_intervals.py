"""The intervals of a fit (:func:`.fitting.fit`): from its Jacobian, from the likelihood ratio
along a severity (where the cost is flat the Jacobian says nothing), and from a moving-block
bootstrap of its residuals. The noise's 95 % intervals, before any model-form calibration
(:mod:`.modelform`).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..physics.faults import FAULTS
from .fitting import BLOCK_ROWS, CHI2_95, SIGNALS, Problem, fit, free_bounds


def jacobian_half(i, x, res, jac, n, n_eff) -> float | None:
    """The half-width of the 95 % interval of coordinate ``x[i]`` from the fit's Jacobian
    (the residual variance and correlation of the fit); None where the residuals do not move
    with it at the fit (a flat stretch: static friction beyond the break-away a run
    reaches), where the Jacobian says nothing; inf where it cannot be inverted."""
    if not np.any(jac[:, i]):
        return None
    s2 = float(np.dot(res, res)) / max(n - len(x), 1)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 * (n / n_eff)
        half = 1.96 * math.sqrt(max(float(cov[i, i]), 0.0))
    except np.linalg.LinAlgError:
        half = math.inf
    return half if math.isfinite(half) else math.inf


def jacobian_interval(fault, i, x, res, jac, n, n_eff) -> tuple[float, float] | None:
    """95 % interval of the severity x[i] of ``fault`` from the fit's Jacobian
    (:func:`jacobian_half`), within the catalog's range; None where it says nothing."""
    spec = FAULTS[fault]
    half = jacobian_half(i, x, res, jac, n, n_eff)
    if half is None:
        return None
    return (max(spec.lo, float(x[i]) - half), min(spec.hi, float(x[i]) + half))


def free_interval(name: str, i, x, res, jac, n, n_eff) -> tuple[float, float] | None:
    """The 95 % interval of free nuisance ``name`` at ``x[i]``, within its bounds."""
    half = jacobian_half(i, x, res, jac, n, n_eff)
    if half is None:
        return None
    lo, hi = free_bounds(name)
    return (max(lo, float(x[i]) - half), min(hi, float(x[i]) + half))


def ratio_interval(problem: Problem, faults: Sequence[str], i: int, x: np.ndarray,
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
    jac_iv = jacobian_interval(faults[i], i, x, res, jac, n, n_eff)
    if jac_iv is not None:
        lo, hi = min(lo, jac_iv[0]), max(hi, jac_iv[1])
    return (float(lo), float(hi))


def bootstrap_intervals(problem: Problem, best, free: list[str], n: int,
                         seed: int) -> list[tuple[float, float]]:
    """Percentile intervals (one per fault of ``best``, a diagnosis Candidate) of ``n`` refits
    to the fitted signals plus moving blocks of the residuals."""
    rng = np.random.default_rng(seed)
    m = len(problem.rows)
    resid = {s: problem.recorded[s] - best.fitted[s] for s in SIGNALS}
    sev = []
    start = best.severities + [best.free[k] for k in free]
    for _ in range(n):
        starts = rng.integers(0, max(1, m - BLOCK_ROWS), size=-(-m // BLOCK_ROWS))
        idx = np.concatenate([np.arange(a, a + BLOCK_ROWS) for a in starts])[:m] % m
        synthetic = {s: best.fitted[s] + resid[s][idx] for s in SIGNALS}
        x, _, _ = fit(problem, best.faults, free, synthetic, [start])
        sev.append(x[:len(best.faults)])
    lo, hi = np.percentile(np.array(sev), [2.5, 97.5], axis=0)
    return [(float(a), float(b)) for a, b in zip(lo, hi)]


__all__ = ['jacobian_half', 'jacobian_interval', 'free_interval', 'ratio_interval',
           'bootstrap_intervals']
