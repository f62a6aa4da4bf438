"""PHM metrics in one place, for the benches and for users: detection (false-alarm and
missed-detection rates, time to detect), interval coverage, and the prognostic metrics of
Saxena et al. (alpha-lambda, prognostic horizon, relative accuracy) -- the last two taken from
``progpy.metrics`` (an extra: ``pip install 'servovalve_twin[progpy]'``) on the RUL samples a
:class:`~.prognosis.Prognosis` draws, so they mean what they mean in progpy.

Conventions: an RUL is in cycles after the cycle of the prediction; an end of life (EOL) is the
cycle of the threshold crossing; a prediction is (cycle, RUL samples); infinite samples (no
crossing) stay infinite, and count as outside any finite bound.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from ..errors import TwinError


def detection_rates(faulty: Sequence[bool], alarmed: Sequence[bool]) -> dict[str, float]:
    """False-alarm rate (alarms among healthy units), missed-detection rate (no alarm among
    faulty units), and the counts."""
    if len(faulty) != len(alarmed):
        raise TwinError(f'detection_rates: {len(faulty)} truths for {len(alarmed)} verdicts')
    f = np.asarray(faulty, dtype=bool)
    a = np.asarray(alarmed, dtype=bool)
    healthy, sick = int((~f).sum()), int(f.sum())
    return dict(false_alarm_rate=float((a & ~f).sum() / healthy) if healthy else math.nan,
                missed_detection_rate=float((~a & f).sum() / sick) if sick else math.nan,
                healthy=healthy, faulty=sick)


def time_to_detect(onset: float, first_alarm: float | None) -> float:
    """The delay from a fault's onset to the first alarm after it; inf when it never came.
    An alarm before the onset is a false alarm, not a detection."""
    if first_alarm is None or first_alarm < onset:
        return math.inf
    return float(first_alarm - onset)


def interval_coverage(truths: Sequence[float], intervals: Sequence[Sequence[float]]
                      ) -> dict[str, float]:
    """How many of ``intervals`` ([lo, hi] each, bounds included) hold their truth."""
    if len(truths) != len(intervals):
        raise TwinError(f'interval_coverage: {len(truths)} truths for {len(intervals)} '
                        'intervals')
    hits = sum(1 for x, (lo, hi) in zip(truths, intervals) if lo <= x <= hi)
    n = len(truths)
    return dict(hits=hits, n=n, coverage=hits / n if n else math.nan)


def relative_accuracy(rul_predicted: float, rul_true: float) -> float:
    """``1 - abs(true - predicted) / true`` (Saxena et al.): 1 is exact; an infinite
    prediction of a finite life is -inf."""
    if not rul_true > 0:
        raise TwinError(f'relative_accuracy: the true RUL must be > 0, got {rul_true!r}')
    return 1.0 - abs(rul_true - rul_predicted) / rul_true


def _profile(predictions: Mapping[float, Sequence[float]]):
    """progpy's ToEPredictionProfile of end-of-life samples (cycle + RUL) per prediction."""
    try:
        from progpy.predictors import ToEPredictionProfile
        from progpy.uncertain_data import UnweightedSamples
    except ImportError:
        raise TwinError('the prognostic metrics use progpy.metrics: pip install '
                        "'servovalve_twin[progpy]'") from None
    profile = ToEPredictionProfile()
    for cycle, rul in sorted(predictions.items()):
        profile[float(cycle)] = UnweightedSamples([{'eol': float(cycle) + float(r)}
                                                   for r in rul])
    return profile


def alpha_lambda(predictions: Mapping[float, Sequence[float]], eol: float, lam: float,
                 alpha: float = 0.2, beta: float = 0.5) -> bool:
    """progpy's alpha-lambda: at the first prediction at or after cycle ``lam``, at least
    ``beta`` of the EOL samples lie within ``alpha`` of the true remaining life around the true
    EOL."""
    from progpy.metrics import alpha_lambda as al
    out = al(_profile(predictions), {'eol': float(eol)}, lambda_value=float(lam),
             alpha=float(alpha), beta=float(beta))
    if out is None:
        raise TwinError(f'alpha_lambda: no prediction at or after cycle {lam:g}')
    return bool(out['eol'])


def prognostic_horizon(predictions: Mapping[float, Sequence[float]], eol: float,
                       alpha: float = 0.2, beta: float = 0.5) -> float | None:
    """progpy's prognostic horizon: true EOL minus the first prediction cycle from which the
    predictions meet the alpha bounds (``beta`` of the samples within ``alpha`` of the true
    remaining life); None when none does."""
    from progpy.metrics import prognostic_horizon as ph

    def criteria(tte, truth):
        bounds = {k: [v - alpha * v, v + alpha * v] for k, v in truth.items()}
        pib = tte.percentage_in_bounds(bounds)
        return {k: pib[k] >= beta for k in truth}

    out = ph(_profile(predictions), criteria, {'eol': float(eol)})
    return None if out['eol'] is None else float(out['eol'])


__all__ = ['detection_rates', 'time_to_detect', 'interval_coverage', 'relative_accuracy',
           'alpha_lambda', 'prognostic_horizon']
