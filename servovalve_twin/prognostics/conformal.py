"""Split-conformal calibration, declared once: the level, the one quantile, the scores.

Every interval and threshold diagnosis states is one rule (Vovk et al., *Algorithmic Learning
in a Random World*; the shape of crepes' ``ConformalRegressor``): over the ``n`` calibration
units of a group, each unit's *nonconformity score* is the smallest value of the interval's
free parameter that would have covered it; the parameter is the ``ceil((1 - alpha)(n + 1))``-th
smallest score (:func:`quantile`). A new unit exchangeable with the group's is then covered
with probability at least ``1 - alpha``, however few the units -- provided ``n`` is at least
:func:`units_needed` (9 at ``alpha`` = 0.1); with fewer, the largest score is the best there is
and the guarantee does not hold, which callers say (:func:`enough`).

The scores, each the closed-form inversion of an interval ``|dev| <= z * half(parameter)``
(``dev`` a unit's error in its fault's coordinate after the bias, ``z`` the normal quantile of
the level, :func:`z_of`):

- :func:`spread_score`: the model-form spread ``sigma`` of ``half = sqrt(se^2 + sigma^2)``,
  ``se`` the unit's own standard error (a normalised score: a precise fit owes its error to
  the model);
- :func:`factor_score`: the factor ``k`` on a flat fit's own error, ``half = sqrt((k se)^2 +
  sigma^2)``;
- :func:`rate_score`: how the spread grows past the alarm value, ``half = sqrt(spread^2 + (rate
  x)^2)`` at a distance ``x`` past it.

Groups (Mondrian conformal prediction) and their fallback order are declared where the
calibration is fitted and read (:func:`.calibration.groups_of`). A p-value of the same
exchangeability, :func:`p_value`, is the goodness-of-fit test's.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import Sequence

import numpy as np

#: the miscoverage every calibrated interval is stated at (a 90 % interval)
ALPHA = 0.1


def z_of(alpha: float = ALPHA) -> float:
    """The standard normal's two-sided ``1 - alpha`` quantile (1.645 at 0.1): the interval's
    half-width in units of its spread."""
    return NormalDist().inv_cdf(1.0 - alpha / 2.0)


def rank(n: int, alpha: float = ALPHA) -> int:
    """The order statistic that bounds ``1 - alpha`` of ``n + 1`` exchangeable units:
    ``ceil((1 - alpha)(n + 1))`` (may exceed ``n``: then no finite bound is guaranteed)."""
    # (the product rounded first: 0.9 * 10 is 9.000000000000002 in binary, whose ceiling 10
    # would ask for one unit more than the rule does)
    return math.ceil(round((1.0 - alpha) * (n + 1), 9))


def units_needed(alpha: float = ALPHA) -> int:
    """The fewest units for which :func:`rank` is at most ``n``."""
    n = 1
    while rank(n, alpha) > n:
        n += 1
    return n


def enough(n: int, alpha: float = ALPHA) -> bool:
    """Whether ``n`` units give a ``1 - alpha`` bound with the conformal guarantee."""
    return rank(n, alpha) <= n


def quantile(scores: Sequence[float] | np.ndarray, alpha: float = ALPHA) -> float:
    """The conformal quantile of ``scores``: the :func:`rank`-th smallest, or the largest
    where there are too few (:func:`enough` says so; callers warn). Raises on no scores."""
    s = np.sort(np.asarray(scores, dtype=float))
    if s.size == 0:
        raise ValueError('a conformal quantile needs at least one score')
    return float(s[min(rank(s.size, alpha), s.size) - 1])


def p_value(reference: Sequence[float], score: float) -> float:
    """The conformal p-value of ``score`` among ``reference`` (sorted ascending): the share of
    the reference scoring as high or higher, with the plus-one rule (never 0)."""
    worse = len(reference) - int(np.searchsorted(reference, score, side='left'))
    return (worse + 1) / (len(reference) + 1)


def _excess(dev: np.ndarray, z: float, floor: np.ndarray | float) -> np.ndarray:
    """``sqrt(max(0, (dev/z)^2 - floor^2))``: what a unit's error asks beyond ``floor``."""
    return np.sqrt(np.maximum(0.0, (np.asarray(dev) / z) ** 2 - np.asarray(floor) ** 2))


def spread_score(dev, se, z: float) -> np.ndarray:
    """The smallest ``sigma`` with ``|dev| <= z * sqrt(se^2 + sigma^2)``."""
    return _excess(dev, z, se)


def factor_score(dev, se, sigma: float, z: float) -> np.ndarray:
    """The smallest ``k`` with ``|dev| <= z * sqrt((k se)^2 + sigma^2)``."""
    return _excess(dev, z, sigma) / np.asarray(se)


def rate_score(dev, spread, x, z: float) -> np.ndarray:
    """The smallest ``rate`` with ``|dev| <= z * sqrt(spread^2 + (rate x)^2)``."""
    return _excess(dev, z, spread) / np.asarray(x)


__all__ = ['ALPHA', 'z_of', 'rank', 'units_needed', 'enough', 'quantile', 'p_value',
           'spread_score', 'factor_score', 'rate_score']
