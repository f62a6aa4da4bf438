"""The live estimator: :func:`~.diagnosis.diagnose` over a moving window, as an
:class:`~.algorithm.Algorithm` -- so it runs in the twin's lockstep (``servovalve-twin run
--estimator SQ``; node ``estimator``), on a bag (``evaluate``) and in sweeps like any algorithm.

Every ``every`` seconds of the run (from ``window`` on) it fits every catalog hypothesis to the
last ``window`` seconds of what it received. The model runs on the received inputs from
``warmup`` seconds before the window, from the received XJ and DXJ there (the spool and flapper
from rest: they settle within milliseconds, and the position loop within the warm-up), so an
estimate costs the same however long the run: about ``window + warmup`` simulated seconds per
model run. Between estimates it holds the last one.

Outputs: ``estimator/<fault>_severity`` for each hypothesis (its fitted severity; NaN before the
first estimate). Health: OK while the verdict is healthy, WARN with the fault named while it is
a fault; key/values ``fault``, ``severity``, ``interval_lo``, ``interval_hi``, ``t_estimate``.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ..physics.valves import get_monitor_model
from ..physics.signals import INPUTS, MEASURED
from .algorithm import OK, WARN, Algorithm, AlgorithmError, Health
from .diagnosis import DIAGNOSABLE, HEALTHY, UNEXPLAINED, diagnose

_SIGNALS = INPUTS + MEASURED


class Estimator(Algorithm):
    """Diagnosis over a moving window (see the module docstring)."""

    inputs = _SIGNALS
    outputs = tuple(f'{f}_severity' for f in DIAGNOSABLE)
    #: model_form: the plant is not the fitted model (a real actuator, HD): the diagnosis'
    #: model-form calibration applies (``run --estimator`` sets it False when they are one)
    parameters = {'model': 'SQ', 'window': 0.5, 'every': 0.25, 'warmup': 0.2, 'faults': 'all',
                  'model_form': True}
    topic_prefix = 'estimator'
    node_name = 'estimator'

    def setup(self, period: float, nominal) -> None:
        super().setup(period, nominal)
        p = self.params
        if not (p['window'] > 0 and p['every'] > 0 and p['warmup'] >= 0):
            raise AlgorithmError(f'estimator: window and every must be > 0 s and warmup >= 0 '
                                 f's, got {p["window"]}, {p["every"]} and {p["warmup"]}')
        self.faults = DIAGNOSABLE if p['faults'] == 'all' else tuple(
            f.strip() for f in p['faults'].split(',') if f.strip())
        unknown = [f for f in self.faults if f not in DIAGNOSABLE]
        if unknown:
            raise AlgorithmError(f'estimator: unknown fault {unknown[0]!r}; expected one of '
                                 f'{list(DIAGNOSABLE)}')
        self.every_ticks = max(1, int(round(p['every'] / period)))
        get_monitor_model(p['model'])            # a simplified model, refused now if not

    def reset(self) -> None:
        # the rows received, from the first one the next estimate needs (older ones dropped)
        self.rows: dict[str, list[float]] = {s: [] for s in ('t',) + _SIGNALS}
        self.ticks = 0
        self.severity = {f: math.nan for f in DIAGNOSABLE}
        self.verdict: Health | None = None

    def step(self, t: float, u: Mapping[str, float]) -> Mapping[str, float]:
        self.rows['t'].append(t)
        for s in _SIGNALS:
            self.rows[s].append(u[s])
        k = self.ticks
        self.ticks += 1
        window = self.params['window']
        if k % self.every_ticks == 0 and t >= window - 1e-12:
            self._estimate(t, window)
        return {f'{f}_severity': self.severity[f] for f in DIAGNOSABLE}

    def _estimate(self, t: float, window: float) -> None:
        p = self.params
        t0 = max(0.0, t - window)
        signals = {s: np.asarray(v) for s, v in self.rows.items()}
        # the kept rows as a run of their own from their first instant
        t_first = float(signals['t'][0])
        signals['t'] = signals['t'] - t_first
        d = diagnose(signals, self.nominal, control_period=self.period, model=p['model'],
                     faults=self.faults, window=(t0 - t_first, t - t_first),
                     start=max(0.0, t0 - p['warmup'] - t_first),
                     model_form=bool(p['model_form']), from_rest=t_first <= 0.0)
        # drop what the next estimate will not need: memory and cost stay bounded
        keep_from = t + self.every_ticks * self.period - window - p['warmup'] - 1e-9
        drop = int(np.searchsorted(signals['t'] + t_first, keep_from))
        for v in self.rows.values():
            del v[:drop]
        for c in d.candidates:
            if c.fault != HEALTHY:
                self.severity[c.fault] = c.severity
        b = d.best
        if d.verdict == UNEXPLAINED:
            self.verdict = Health(WARN, f'unexplained (best candidate {b.fault})',
                                  dict(fault=UNEXPLAINED, t_estimate=t))
        elif b.fault == HEALTHY:
            self.verdict = Health(OK, 'healthy', dict(fault=HEALTHY, t_estimate=t))
        else:
            self.verdict = Health(WARN, f'{b.fault} {b.severity:.4g}', dict(
                fault=b.fault, severity=b.severity, interval_lo=b.interval[0],
                interval_hi=b.interval[1], t_estimate=t))

    def health(self) -> Health | None:
        return self.verdict


__all__ = ['Estimator']
