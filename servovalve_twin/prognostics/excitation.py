"""What a flight can reveal: each catalog fault's detection limit and severity resolution on
a scenario, and a designed pre-flight built-in test (PBIT) that reveals every fault.

The reading is that of :mod:`.diagnosis` (fault hypotheses fitted with the simplified model,
ranked by an information criterion), linearised around healthy on the scenario's inputs:

- the *signature* of fault ``f`` at severity ``s`` is the simplified model's output change
  ``d_f(s) = y(f, s) - y(healthy)``, in the residual scales of diagnosis (XJ, DXJ, P12 stacked);
  the part a free nuisance (``free``: M, CJ at 1.5 x their documented spread) can absorb is
  projected out;
- the *floor* is what a healthy unit leaves after the fit: the model-form mismatch of the
  simplified model against HD flying the same inputs with the design parameters, plus the
  documented sensor noise, ``RSS0 = |y_HD - y|^2 + n*noise^2``; its lag-1 correlation gives the
  effective sample size ``n_eff`` (as in diagnosis);
- the fault is *detectable* at ``s`` when the fault hypothesis beats healthy by
  :data:`EVIDENCE` in the criterion, ``n_eff*ln(1 + |d_f(s)|^2/RSS0) >= ln(n_eff) + EVIDENCE``,
  i.e. ``|d_f(s)|^2/RSS0 >= kappa`` (:func:`kappa`); and, as the verdict rule of diagnosis
  asks, at least :data:`~.diagnosis.DETECTABLE` of the way from healthy to its alarm value.
  The *detection limit* is the smallest such severity (bisection along the fault's own
  coordinate, geometric for a multiplier), ``None`` where even the catalog's bound is not;
- the *resolution* is the half-width of a nominal 90 % interval at the mild severity (0.3 of
  the way to the alarm value) from the Fisher information of the signature with the floor's
  variance and correlation, widened by the calibrated model-form spread where the packaged
  calibration has one (:mod:`.calibration`), as a fraction of the severity's distance from
  healthy.

Two faults are told apart when neither signature at the mild severity is a multiple of the
other's: the *separation* ``min(|d_a - c d_b|^2)`` over ``c``, the smaller of both ways, over
``RSS0``, again against ``kappa``.

The built-in test (:func:`design_bit`) is a command and load profile of a few seconds in three
parts -- steps (spool and valve bandwidth, gain, supply), a slow ramp under load (stick-slip:
static and dynamic friction, null bias) and holds under alternating load (leakage, stiffness)
-- whose amplitudes, load levels, ramp rate and part lengths maximise the smallest of every
fault's detectability margin and every pair's separation margin at the mild severities (a
max-min design criterion, the E-optimal flavour of optimal input design), by a seeded random
search then coordinate refinement, within the rig's limits (stroke, load, command rate).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.faults import FAULTS, combine
from ..physics.params import DEFAULTS, EhaParams
from ..physics.scenario import Scenario, as_scenario
from ..physics.simulate import simulate
from .calibration import alpha_of
from .calibration_set import LEVELS, NOISE, VARY, from_g, severity_at, to_g
from .conformal import z_of
from .diagnosis import DETECTABLE, DIAGNOSABLE
from .fitting import RESIDUAL_SCALE, SIGNALS, effective_n

#: evidence a fault must have over healthy to count as detected (BIC points; "very strong"
#: on Kass and Raftery's scale, as a pair needs in diagnosis)
EVIDENCE = 10.0
#: the severity at which resolution and separation are read: the calibration's mild level
MILD = LEVELS[0]
#: the nuisance a unit may carry, as a multiple of the documented spread (VARY)
NUISANCE_SPREAD = 1.5
#: the plant whose mismatch with the model is the floor
REFERENCE_PLANT = 'HD'


def kappa(n_eff: float) -> float:
    """The signature-to-floor ratio a fault needs to beat healthy by :data:`EVIDENCE` with one
    parameter more: ``exp((ln n_eff + EVIDENCE)/n_eff) - 1``."""
    return math.expm1((math.log(n_eff) + EVIDENCE) / n_eff)


def _vector(signals: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.concatenate([np.asarray(signals[s], dtype=float) / RESIDUAL_SCALE[s]
                           for s in SIGNALS])


class Excitation:
    """A scenario's inputs under the simplified ``model``: the healthy run, the floor and the
    signature of any fault (each severity simulated once)."""

    def __init__(self, scenario: Scenario | Mapping[str, Any] | str, design: EhaParams = DEFAULTS,
                 *, model: str = 'SQ', control_period: float = 1e-3,
                 free: Sequence[str] = ('CJ', 'M'), onset: float = 0.0):
        if isinstance(scenario, str):
            from ..config import load_scenario
            scenario = load_scenario(scenario)
        self.scenario = as_scenario(scenario).without_faults().without_sensors()
        if not 0.0 <= onset < self.scenario.duration:
            raise TwinError(f'onset {onset:g} s lies outside the flight [0, '
                            f'{self.scenario.duration:g}) s')
        #: when the faults of the signatures begin [s]: what part of the flight shows them
        self.onset = float(onset)
        self.design, self.model, self.period = design, model, control_period
        self.healthy = self._run(design)
        mismatch = _vector(simulate(REFERENCE_PLANT, self.scenario, params=design,
                                    ecu_period=control_period).signals) - self.healthy
        self.n = len(mismatch)
        m = self.n // len(SIGNALS)
        noise = sum(m * (NOISE[s] / RESIDUAL_SCALE[s]) ** 2 for s in SIGNALS)
        self.rss0 = float(mismatch @ mismatch) + noise
        self.n_eff = effective_n(mismatch, len(SIGNALS))
        self.kappa = kappa(self.n_eff)
        # the directions a free nuisance can take, orthonormal (the signatures are projected
        # off them: a fault that looks like a heavier jack is no fault to a fit that frees M)
        cols = [self._run(design.replace(**{p: design.value(p) * (1 + NUISANCE_SPREAD * VARY
                                                                  .get(p, 0.2))}))
                - self.healthy for p in free]
        self.nuisance = (np.linalg.qr(np.array(cols).T)[0] if cols
                         else np.zeros((self.n, 0)))
        self._sig: dict[tuple[str, float], np.ndarray] = {}

    def _run(self, params: EhaParams, faults: tuple = ()) -> np.ndarray:
        scn = dataclasses.replace(self.scenario, faults=faults) if faults else self.scenario
        return _vector(simulate(self.model, scn, params=params,
                                ecu_period=self.period).signals)

    def signature(self, fault: str, severity: float) -> np.ndarray:
        """``d_f(s)`` with the free nuisance's directions projected out; the fault from
        :attr:`onset` on."""
        key = (fault, float(severity))
        if key not in self._sig:
            if self.onset:
                d = self._run(self.design, (dict(at=self.onset, fault=fault,
                                                 severity=float(severity)),))
            else:
                d = self._run(combine(self.design, {fault: float(severity)}))
            d = d - self.healthy
            self._sig[key] = d - self.nuisance @ (self.nuisance.T @ d)
        return self._sig[key]

    def margin(self, fault: str, severity: float) -> float:
        """``|d_f(s)|^2 / (kappa RSS0)``: 1 at the detection limit."""
        d = self.signature(fault, severity)
        return float(d @ d) / (self.kappa * self.rss0)

    def separation(self, a: str, b: str, q: float = MILD) -> float:
        """The smaller of ``min_c |d_a - c d_b|^2`` and the reverse at ``q`` of the way to
        each alarm value, over ``kappa RSS0`` (1: just told apart)."""
        da, db = self.signature(a, severity_at(a, q)), self.signature(b, severity_at(b, q))
        worst = math.inf
        for u, v in ((da, db), (db, da)):
            vv = float(v @ v)
            rest = u - (float(u @ v) / vv) * v if vv > 0 else u
            worst = min(worst, float(rest @ rest))
        return worst / (self.kappa * self.rss0)

    def detection_limit(self, fault: str) -> float | None:
        """The smallest severity detected (see the module docstring), None if none is."""
        spec = FAULTS[fault]
        up = spec.demo > spec.healthy
        bound = spec.hi if up else spec.lo
        g_far = to_g(fault, bound)
        # the verdict rule of diagnosis: nothing below DETECTABLE of the way to the alarm
        rule = from_g(fault, DETECTABLE * to_g(fault, spec.demo))
        if self.margin(fault, bound) < 1.0:
            return None
        lo, hi = 0.0, g_far                    # in g: margin(lo) < 1 <= margin(hi)
        for _ in range(24):
            mid = 0.5 * (lo + hi)
            if self.margin(fault, from_g(fault, mid)) >= 1.0:
                hi = mid
            else:
                lo = mid
        s = from_g(fault, hi)
        return float(max(s, rule) if up else min(s, rule))

    def resolution(self, fault: str, q: float = MILD,
                   calibration: Mapping[str, Any] | None = None) -> float:
        """Half-width of the calibration's interval (90 %) at ``q`` of the way to the alarm
        value, relative to the severity's distance from healthy (0.1: +-10 %)."""
        spec = FAULTS[fault]
        s = severity_at(fault, q)
        g = to_g(fault, s)
        h = 0.01 * abs(to_g(fault, spec.demo))
        jac = (self.signature(fault, from_g(fault, g + h))
               - self.signature(fault, from_g(fault, g - h))) / (2 * h)
        info = float(jac @ jac)
        var = self.rss0 / self.n * (self.n / self.n_eff)       # per-sample, correlation
        se = math.sqrt(var / info) if info > 0 else math.inf
        sigma = ((calibration or {}).get('faults', {}).get(fault) or {}).get('sigma', 0.0)
        half = z_of(alpha_of(calibration)) * math.hypot(se, sigma)
        if not math.isfinite(half):
            return math.inf
        width = abs(from_g(fault, g + half) - from_g(fault, g - half)) / 2
        return width / abs(s - spec.healthy)


@dataclasses.dataclass
class Limit:
    """One fault's detection limit and resolution on a scenario."""

    fault: str
    limit: float | None          # the smallest severity detected; None: none in the catalog
    mild: float                  # the mild severity (0.3 of the way to the alarm value)
    resolution: float            # relative 90 % half-width at the mild severity
    margin: float                # detectability margin at the mild severity (>= 1: detected)

    def detects(self, severity: float) -> bool:
        """Whether ``severity`` lies at or beyond the limit (a fault below it may be called
        healthy: the flight cannot show it)."""
        h = FAULTS[self.fault].healthy
        return self.limit is not None and abs(self.limit - h) <= abs(severity - h) + 1e-12

    @property
    def detects_mild(self) -> bool:
        return self.detects(self.mild)

    def to_json(self) -> dict[str, Any]:
        return dict(fault=self.fault, limit=self.limit, mild=self.mild,
                    detects_mild=self.detects_mild, resolution=self.resolution,
                    margin=self.margin)


#: the nuisance freed where a limit's caller does not say (what the README recommends for
#: diagnose): `bit` and `diagnose --limits` read their limits with it alike (with different
#: defaults the same "resolution on paper" column differed: a leak +-22.6 % against +-29.5 %)
LIMITS_FREE = ('CJ', 'M')


def detection_limits(scenario, design: EhaParams = DEFAULTS, *, model: str = 'SQ',
                     control_period: float = 1e-3, free: Sequence[str] = LIMITS_FREE,
                     faults: Sequence[str] = DIAGNOSABLE, onset: float = 0.0) -> list[Limit]:
    """Each fault's detection limit and severity resolution on ``scenario``, for faults that
    begin at ``onset`` [s] (0: present from the start)."""
    from .calibration import calibration_for
    for f in faults:
        if f not in DIAGNOSABLE:
            raise TwinError(f'unknown fault {f!r} for a detection limit; expected one of '
                            f'{list(DIAGNOSABLE)}')
    exc = Excitation(scenario, design, model=model, control_period=control_period, free=free,
                     onset=onset)
    cal = calibration_for(model, free)
    return [Limit(fault=f, limit=exc.detection_limit(f), mild=severity_at(f, MILD),
                  resolution=exc.resolution(f, calibration=cal),
                  margin=exc.margin(f, severity_at(f, MILD)))
            for f in faults]


def format_limits(columns: Mapping[str, Sequence[Limit]],
                  free: Sequence[str] = LIMITS_FREE) -> str:
    """A table, one row per fault, the limit and resolution per named scenario; a line under it
    says with which nuisance free they hold."""
    names = list(columns)
    head = '| fault | mild | ' + ' | '.join(f'limit on {n} | resolution on {n}'
                                              for n in names) + ' |'
    lines = [head, '|' + '---|' * (2 + 2 * len(names))]
    for i, lim in enumerate(next(iter(columns.values()))):
        cells = [lim.fault, f'{lim.mild:.4g}']
        for n in names:
            x = columns[n][i]
            cells.append('not detectable' if x.limit is None else
                         f'{x.limit:.4g}' + ('' if x.detects_mild else ' (above mild)'))
            cells.append('-' if not math.isfinite(x.resolution) else f'+-{x.resolution:.1%}')
        lines.append('| ' + ' | '.join(cells) + ' |')
    lines.append(f'(diagnosed with {",".join(sorted(free)) or "no nuisance"} free)')
    return '\n'.join(lines)


# -- the designed built-in test -------------------------------------------------------------

#: the design variables of the built-in test, each with its range as a fraction of the rig's
#: limit (stroke, load) or in its own unit
BIT_VARIABLES = {
    'step': (0.1, 1.0),          # step amplitude, fraction of the stroke limit
    'step_load': (-1.0, 1.0),    # load during the steps, fraction of the load limit
    'ramp_rate': (2e-4, 2e-2),   # slow-ramp command rate [m/s] (log-uniform)
    'ramp_load': (-1.0, 1.0),    # load during the ramp
    'hold_load': (0.1, 1.0),     # load magnitude of the holds (+ then -)
    'steps_part': (0.2, 0.5),    # share of the duration: steps
    'ramp_part': (0.2, 0.6),     # share: ramp (the holds take the rest, at least 0.1)
}
#: the shortest built-in test that can excite every part (a few step responses, a ramp, two
#: holds)
MIN_BIT_DURATION = 0.6


@dataclasses.dataclass(frozen=True)
class RigLimits:
    """What the test rig and the actuator allow: stroke ``|Com|`` [m], load ``|FR|`` [N],
    command rate [m/s] (None: steps)."""

    stroke: float = 0.04
    load: float = 6000.0
    rate: float | None = None

    def check(self, design: EhaParams) -> None:
        if not (math.isfinite(self.stroke) and 0 < self.stroke <= 0.9 * design.XJM):
            raise TwinError(f'BIT stroke {self.stroke!r} m: allowed (0, {0.9 * design.XJM:g}] '
                            'm (0.9 of the end stops)')
        stall = design.AJ * design.PSRN
        if not (math.isfinite(self.load) and 0 <= self.load <= 0.8 * stall):
            raise TwinError(f'BIT load {self.load!r} N: allowed [0, {0.8 * stall:.0f}] N (0.8 '
                            'of the stall force AJ*PSRN)')
        if self.rate is not None and not (math.isfinite(self.rate) and self.rate >= 0.05):
            raise TwinError(f'BIT max rate {self.rate!r} m/s: allowed >= 0.05 m/s (slower '
                            'cannot excite the valve bandwidth), or no limit')


def bit_scenario(x: Mapping[str, float], duration: float, rig: RigLimits,
                 name: str = 'bit') -> dict[str, Any]:
    """The built-in test's scenario for design variables ``x`` (see :data:`BIT_VARIABLES`)."""
    ms = 1e-3
    t_steps = round(duration * x['steps_part'], 3)
    t_ramp = round(duration * x['ramp_part'], 3)
    n_steps = 4
    dwell = (t_steps - 0.01) / n_steps
    a = rig.stroke * x['step']
    if rig.rate:
        # a rate-limited swing of 2a must leave half its dwell settled
        a = min(a, rig.rate * dwell / 4)
    # command: rate-limited moves (one control period where the rig has no rate limit)
    pts: list[list[float]] = [[0.0, 0.0]]

    def move(t: float, to: float) -> float:
        last = pts[-1][1]
        dt = max(ms, abs(to - last) / rig.rate) if rig.rate else ms
        pts.append([round(t, 6), last])
        pts.append([round(t + dt, 6), to])
        return t + dt

    t = 0.01
    for k in range(n_steps):
        move(t, a if k % 2 == 0 else -a)
        t += dwell
    # the slow ramp: across the stroke's middle, at the designed rate, from where the steps
    # left (-a) towards +a, as far as the time allows
    t = t_steps
    rate = min(x['ramp_rate'], rig.rate) if rig.rate else x['ramp_rate']
    reach = min(2 * a, rate * (t_ramp - 0.02))
    t = move(t, -a) + 0.01
    pts.append([round(t_steps + t_ramp - 0.01, 6), -a + reach])
    t = t_steps + t_ramp
    move(t, 0.0)
    pts.append([duration, 0.0])
    hold = duration - t_steps - t_ramp
    load = rig.load
    fr = [[0.0, 0.0], [0.005, round(x['step_load'] * load, 1)],
          [t_steps, round(x['ramp_load'] * load, 1)],
          [round(t_steps + t_ramp + 0.05 * hold, 6), round(x['hold_load'] * load, 1)],
          [round(t_steps + t_ramp + 0.55 * hold, 6), round(-x['hold_load'] * load, 1)]]
    return dict(name=name, description='pre-flight built-in test designed by servovalve-twin '
                'bit: steps, a slow ramp under load, holds under alternating load',
                duration=duration, com={'ramp': pts}, fr=fr, psr=[[0.0, 2.0e7]],
                windows={'steps': [0.0, t_steps], 'ramp': [t_steps, t_steps + t_ramp],
                         'holds': [t_steps + t_ramp, duration]})


def bit_criterion(exc: Excitation, faults: Sequence[str] = DIAGNOSABLE) -> float:
    """The design criterion: the log of the smallest margin -- each fault's detectability at
    the mild severity and each pair's separation (>= 0: all detected and told apart)."""
    worst = min(exc.margin(f, severity_at(f, MILD)) for f in faults)
    for i, a in enumerate(faults):
        for b in faults[i + 1:]:
            worst = min(worst, exc.separation(a, b))
    return math.log(max(worst, 1e-300))


def design_bit(duration: float = 2.0, rig: RigLimits = RigLimits(), *,
               design: EhaParams = DEFAULTS, model: str = 'SQ', seed: int = 0,
               candidates: int = 24, refine: int = 2,
               faults: Sequence[str] = DIAGNOSABLE) -> tuple[dict[str, Any], float]:
    """The built-in test's scenario and its criterion (:func:`bit_criterion`): a seeded
    random search over :data:`BIT_VARIABLES`, then ``refine`` rounds of coordinate steps
    (halved each round). About 10 model runs per candidate."""
    if not (math.isfinite(duration) and MIN_BIT_DURATION <= duration <= 60.0):
        raise TwinError(f'BIT duration {duration!r} s: allowed [{MIN_BIT_DURATION:g}, 60] s '
                        '(shorter cannot hold a step response, a ramp and two holds)')
    rig.check(design)
    rng = np.random.default_rng(seed)

    def score(x):
        if x['steps_part'] + x['ramp_part'] > 0.9:
            return -math.inf
        return bit_criterion(Excitation(bit_scenario(x, duration, rig), design, model=model),
                             faults)

    def draw():
        out = {}
        for k, (lo, hi) in BIT_VARIABLES.items():
            u = rng.uniform()
            out[k] = lo * (hi / lo) ** u if k == 'ramp_rate' else lo + u * (hi - lo)
        return out

    best, best_j = None, -math.inf
    for _ in range(candidates):
        x = draw()
        j = score(x)
        if j > best_j:
            best, best_j = x, j
    step = 0.25
    for _ in range(refine):
        for k, (lo, hi) in BIT_VARIABLES.items():
            for sign in (1, -1):
                y = dict(best)
                if k == 'ramp_rate':
                    y[k] = min(max(y[k] * math.exp(sign * step * math.log(hi / lo)), lo), hi)
                else:
                    y[k] = min(max(y[k] + sign * step * (hi - lo), lo), hi)
                j = score(y)
                if j > best_j:
                    best, best_j = y, j
        step /= 2
    scn = bit_scenario(best, duration, rig)
    scn['description'] += (f'; criterion {best_j:+.3f} (log of the smallest detectability or '
                           f'separation margin at the mild severities; >= 0: all met); seed '
                           f'{seed}')
    return scn, best_j


__all__ = ['Excitation', 'Limit', 'RigLimits', 'detection_limits', 'format_limits',
           'design_bit', 'bit_scenario', 'bit_criterion', 'kappa', 'EVIDENCE',
           'MIN_BIT_DURATION']
