"""What a diagnosis answers (:mod:`.diagnosis`): each hypothesis fitted (:class:`Candidate`)
and the whole answer (:class:`Diagnosis`) -- the verdict, its confidence and what it counts,
identifiability, goodness of fit -- and its JSON."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

HEALTHY = 'healthy'
UNEXPLAINED = 'unexplained'
#: catalog faults a simplified model cannot hypothesise (HD geometry it has not), and the
#: verdicts they are read as (measured on HD units, bench/bench_diagnosis.py: clearance growth
#: as leakage growth or supply loss): such a verdict says it is also consistent with them
CONFUSABLE = {'leakage_growth': ('clearance_growth',), 'supply_loss': ('clearance_growth',)}


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
    #: each free nuisance's 95 % interval from the fit's Jacobian (a factor, or a sensor
    #: offset in SI), by name
    free_intervals: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)

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
    #: the simplified model's own misfit on this flight: the RMS of its nominal run against
    #: HD's nominal run on the recorded inputs (None: not computed)
    flight_model_form_rms: float | None = None
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
    #: the onset fit's cost per tried instant (``costs``, the best ``rss``, the likelihood-
    #: ratio ``width``): what the calibration reads the onset interval's factor from; not in
    #: the JSON
    onset_profile: dict[str, Any] | None = None
    #: per fault of the verdict: '' where the data pin its severity, else the one-sided bound
    #: they support ('static_friction >= 12.3': the likelihood is flat beyond)
    bounds: list[str] = dataclasses.field(default_factory=list)
    #: the hypotheses that fit this run as well as the verdict (within the evidence a pair
    #: needs, from the start or from an onset): the run cannot tell them from it
    rivals: list[str] = dataclasses.field(default_factory=list)

    @property
    def identifiable(self) -> bool:
        return not any(self.bounds)

    @property
    def also_consistent_with(self) -> list[str]:
        """Catalog faults the verdict cannot be told from: those outside the hypotheses that
        SQ confuses with it, and the hypotheses that fit this run as well (:attr:`rivals`)."""
        if self.verdict:
            return []
        return sorted({o for f in self.best.faults for o in CONFUSABLE.get(f, ())}
                      | set(self.rivals))

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
                    fit=dict(rms=self.fit_rms, p_value=self.p_value, limit=self.fit_limit,
                             flight_model_form_rms=self.flight_model_form_rms),
                    identifiable=self.identifiable, bounds=[b for b in self.bounds if b],
                    also_consistent_with=self.also_consistent_with,
                    onset=None if unexplained else self.onset,
                    nuisance={k: dict(value=v, interval=list(b.free_intervals[k]))
                              if k in b.free_intervals else dict(value=v, interval=None)
                              for k, v in b.free.items()},
                    candidates=[c.to_json() for c in self.candidates], model=self.model,
                    window=list(self.window), calibration=self._calibration_json(),
                    warnings=list(self.warnings))

    def _calibration_json(self) -> dict[str, Any] | None:
        """Which model-form calibration was applied: the flight's own (its cache key, the
        verdict floor and the healthy units it stands on) or the packaged one (and which of
        its flights' entries); None: none (noise-only intervals)."""
        cal = self.calibration
        if cal is None:
            return None
        if 'verdict_fraction' in cal:
            about = cal.get('about', {})
            return dict(source='flight', key=about.get('key'), units=about.get('units'),
                        healthy_units=cal.get('healthy_units'),
                        verdict_fraction=cal['verdict_fraction'])
        return dict(source='packaged', flight=self.calibration_scenario)


__all__ = ['Candidate', 'Diagnosis', 'HEALTHY', 'UNEXPLAINED', 'CONFUSABLE']
