"""The least-squares machinery of the diagnosis (:mod:`.diagnosis`) on one recorded run: the
run cut to its window and the model run per parameter set (:class:`Problem`), the bounded fit
of a hypothesis' severities and nuisance factors (:func:`fit`), the effective sample size of
correlated residuals. The intervals of a fit: :mod:`.fit_intervals`."""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from ..errors import ModelError, TwinError
from ..physics.faults import FAULTS, combine
from ..physics.params import PARAM_FIELDS, PARAM_NAMES, EhaParams
from ..physics.scenario import Profile, Scenario
from ..physics.signals import MEASURED
from ..physics.simulate import simulate
from ..physics.valves import get_monitor_model

SIGNALS = MEASURED
#: residual scales [SI]: about SQ's RMS error against HD on the paper scenario
#: (doc/results/against-hd.md)
RESIDUAL_SCALE = {'xj': 2.0e-4, 'dxj': 3.0e-3, 'p12': 2.0e5}
#: nuisance factors on the design values
FREE_BOUNDS = (0.5, 2.0)
#: sensor offsets a run reads with: name -> signal. An offset of XJ's sensor is inside the
#: loop -- the ECU reads the biased XJ, so the jack settles ``b`` short of the command and the
#: reading shows the command: exactly a run with the command less ``b`` (the ECU's law is
#: GAP*(Com - XJ)), read ``b`` high. DXJ and P12 are read, not fed back: their offsets add to
#: the readings only.
SENSOR_BIAS = {'xj_bias': 'xj', 'dxj_bias': 'dxj', 'p12_bias': 'p12'}
#: the offsets a fit can free beside the factors (``--free p12_bias,...``). Not XJ's: the loop
#: drives the reading, not the jack, to the command and the plant is the same at every
#: position, so the offset shows only in the first milliseconds from rest, where SQ's own
#: mismatch against HD is as large (freed on a healthy HD unit it read -119 um, its interval
#: [-200, -21] um excluding the truth 0: measured). A known one (a bag's ``sensors:``) is
#: applied.
FREEABLE_BIAS = ('dxj_bias', 'p12_bias')
#: the offsets a fit considers [SI], +-: 20 x the documented noise of each sensor (10 um, 1 mm/s,
#: 50 kPa), beyond which a reading is a broken sensor, not a biased one
BIAS_BOUNDS = {'xj_bias': 2.0e-4, 'dxj_bias': 2.0e-2, 'p12_bias': 1.0e6}
#: no sensor offset (xj, dxj, p12)
NO_BIAS = (0.0, 0.0, 0.0)


class Point(NamedTuple):
    """What a model run is: the parameters and the sensors' offsets (xj, dxj, p12) [SI]."""

    params: EhaParams
    bias: tuple[float, float, float] = NO_BIAS


def free_bounds(name: str) -> tuple[float, float]:
    """A free nuisance's bounds: a factor's on its design value, or a sensor offset's [SI]."""
    if name in SENSOR_BIAS:
        return (-BIAS_BOUNDS[name], BIAS_BOUNDS[name])
    return FREE_BOUNDS


def free_start(name: str) -> float:
    """A free nuisance at the design: factor 1, offset 0."""
    return 0.0 if name in SENSOR_BIAS else 1.0
BLOCK_ROWS = 50
#: chi-square with one degree of freedom at 95 %
CHI2_95 = 3.841


class Problem:
    """The recorded run cut to the window, and the model run for one parameter set."""

    def __init__(self, signals: Mapping[str, np.ndarray], design: EhaParams, model: str,
                 control_period: float, window: tuple[float, float] | None,
                 start: float | None = None, from_rest: bool = True,
                 sensor_bias: Mapping[str, float] | None = None):
        missing = [s for s in ('t', 'com', 'fr', 'psr') + SIGNALS
                   if s not in signals or not np.all(np.isfinite(signals[s]))]
        if missing:
            raise TwinError(f'the run lacks {", ".join(missing)} (a diagnosis needs the '
                            'recorded /com, /fr, /psr, /xj, /dxj and /p12 at every 1 ms row)')
        get_monitor_model(model)
        self.model = model
        # derived parameters (C4_alpha from CLk, ...) derive again under each hypothesis, as
        # they do when the twin injects a fault; a bag's provenance lists them resolved
        self.design = design.replace(**{n: None for n in PARAM_NAMES
                                        if PARAM_FIELDS[n].default is None})
        self.control_period = control_period
        t = np.asarray(signals['t'], dtype=float)
        ms = np.rint(t * 1000).astype(np.int64)
        t_last = ms[-1] / 1000
        t0, t1 = window if window is not None else (0.0, t_last)
        if not (0.0 <= t0 < t1 <= t_last + 1e-9):
            raise TwinError(f'window {t0:g}:{t1:g} s lies outside the run [0, {t_last:g}] s '
                            '(T0 < T1 needed)')
        self.window = (float(t0), float(t1))
        start = 0.0 if start is None else float(start)
        if not 0.0 <= start <= t0 + 1e-9:
            raise TwinError(f'start {start:g} s must lie in [0, {t0:g}] (the window start)')
        n_end = int(round(t1 * 1000))
        n_start = int(round(start * 1000))
        # the model runs from `start`, time shifted to 0, from the recorded jack state there
        # (the spool and flapper from rest: they settle within milliseconds); a whole run
        # (``from_rest``: its first row is its start) starts at rest -- not at its first
        # recorded sample, which is the rest state plus the sensors' noise: started there, the
        # model made a transient the actuator never had
        self.initial = ({} if n_start == 0 and from_rest else
                        {s: float(signals[s][n_start]) for s in ('xj', 'dxj')})
        # inputs in force from each 1 ms row on (piecewise constant, as the twin holds them)
        profiles = {s: Profile('steps', tuple(zip(((ms[n_start:n_end + 1] - n_start) / 1000
                                                   ).tolist(),
                                                  np.asarray(signals[s][n_start:n_end + 1],
                                                             dtype=float).tolist())))
                    for s in ('com', 'fr', 'psr')}
        self.scenario = Scenario(name='recorded', duration=(n_end - n_start) / 1000, **profiles)
        keep = (ms >= int(round(t0 * 1000))) & (ms <= n_end)
        self.rows = np.flatnonzero(keep)
        self.model_rows = self.rows - n_start
        self.recorded = {s: np.asarray(signals[s], dtype=float)[self.rows] for s in SIGNALS}
        self.t = t[self.rows]
        self.evaluations = 0
        self._runs: dict[tuple, dict[str, np.ndarray] | None] = {}
        self.t_start = n_start / 1000                  # run time of the model's t = 0
        # the sensors' offsets the run is known to have (a bag's recorded sensor model), by
        # signal; a free offset adds to them
        known = dict(sensor_bias or {})
        self.known_bias = tuple(float(known.get(s, 0.0)) for s in SENSOR_BIAS.values())
        self._scenarios: dict[float, Scenario] = {0.0: self.scenario}

    def _scenario_for(self, xj_bias: float) -> Scenario:
        """The recorded inputs for a run whose XJ sensor reads ``xj_bias`` high: the command
        less it (see :data:`SENSOR_BIAS`)."""
        if xj_bias not in self._scenarios:
            com = self.scenario.com
            self._scenarios[xj_bias] = dataclasses.replace(self.scenario, com=dataclasses.replace(
                com, points=tuple((t, v - xj_bias) for t, v in com.points)))
        return self._scenarios[xj_bias]

    def _initial_for(self, xj_bias: float) -> dict[str, float]:
        # a recorded XJ to start from is the reading: the jack is ``xj_bias`` below it
        if xj_bias and 'xj' in self.initial:
            return dict(self.initial, xj=self.initial['xj'] - xj_bias)
        return self.initial

    def _readings(self, r, bias: tuple[float, float, float]) -> dict[str, np.ndarray]:
        return {s: r[s][self.model_rows] + b if b else r[s][self.model_rows]
                for s, b in zip(SIGNALS, bias)}

    def params(self, faults: Sequence[str], severities: Sequence[float],
               free: Mapping[str, float]) -> Point:
        """The run of ``faults`` at ``severities`` with the ``free`` nuisance: factors on the
        design's values, sensor offsets (:data:`SENSOR_BIAS`) beside the known ones."""
        nominal = self.design.replace(**{k: self.design.value(k) * v for k, v in free.items()
                                         if k not in SENSOR_BIAS})
        bias = tuple(k + float(free.get(name, 0.0))
                     for k, name in zip(self.known_bias, SENSOR_BIAS))
        return Point(combine(nominal, dict(zip(faults, severities))), bias)

    def run(self, point: Point | EhaParams, events: tuple = ()
            ) -> dict[str, np.ndarray] | None:
        """The model's window rows, as the sensors read them, for ``point`` (None if the
        model failed); each point runs once -- the fitted signals of a hypothesis are those
        of its last solver evaluations, not a run more. ``events``: faults scheduled during
        the run, ``(at [s, run time], fault, severity)`` each (an onset)."""
        params, bias = point if isinstance(point, Point) else (point, self.known_bias)
        key = (params, events, bias)
        if key not in self._runs:
            self.evaluations += 1
            scn = self._scenario_for(bias[0])
            if events:
                scn = dataclasses.replace(scn, faults=tuple(
                    dict(at=at - self.t_start, fault=f, severity=sev) for at, f, sev in events))
            try:
                r = simulate(self.model, scn, params=params, ecu_period=self.control_period,
                             initial=self._initial_for(bias[0]))
                self._runs[key] = self._readings(r, bias)
            except ModelError:
                self._runs[key] = None
        return self._runs[key]

    def run_many(self, runs: Sequence[tuple[EhaParams, tuple]]) -> None:
        """Run the (parameters, events) of ``runs`` not run yet as one fleet
        (:func:`~..physics.fleet.simulate_many`) where the model runs faster so (its registry
        entry's ``fleet_pays``), else one by one: :meth:`run` then finds each, the rows it
        would have run alone (bit for bit)."""
        from ..physics.valves import get_valve_model
        points = [(p if isinstance(p, Point) else Point(p, self.known_bias), ev)
                  for p, ev in runs]
        todo = list(dict.fromkeys((p, ev, b) for (p, b), ev in points
                                  if (p, ev, b) not in self._runs))
        if len(todo) < 2 or not get_valve_model(self.model).fleet_pays:
            for params, events, bias in todo:
                self.run(Point(params, bias), events)
            return
        from ..physics.fleet import simulate_many
        self.evaluations += len(todo)
        # one fleet per XJ offset (a command of its own); a finite difference in it is one
        # point apart
        for xj_bias in dict.fromkeys(k[2][0] for k in todo):
            group = [k for k in todo if k[2][0] == xj_bias]
            faults = [tuple(dict(at=at - self.t_start, fault=f, severity=sev)
                            for at, f, sev in events) for _, events, _ in group]
            got = simulate_many(self.model, self._scenario_for(xj_bias), [p for p, _, _ in group],
                                ecu_period=self.control_period,
                                initial=self._initial_for(xj_bias), faults=faults,
                                failed='none')
            for key, r in zip(group, got):
                self._runs[key] = None if r is None else self._readings(r, key[2])

    def fleet_map(self, to_run):
        """A map for scipy's finite differences (``least_squares(workers=...)``): the points
        it asks for, turned into runs by ``to_run(x)``, are run as one fleet first; then the
        residuals are taken point by point as scipy would -- the same Jacobian, faster."""
        def mapper(func, xs):
            xs = list(xs)
            self.run_many([to_run(x) for x in xs])
            return [func(x) for x in xs]
        return mapper

    def residuals(self, fitted: dict[str, np.ndarray] | None,
                  recorded: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        recorded = self.recorded if recorded is None else recorded
        if fitted is None:                      # the model failed here: far from any fit
            return np.full(len(SIGNALS) * len(self.rows), 1e3)
        return np.concatenate([(fitted[s] - recorded[s]) / RESIDUAL_SCALE[s] for s in SIGNALS])


def start_grid(name: str, n: int = 7) -> list[float]:
    """Severities to start from: geometric for multipliers, even for fractions and values."""
    f = FAULTS[name]
    if f.kind == 'scale':
        grid = [f.lo * (f.hi / f.lo) ** q for q in np.linspace(0.0, 1.0, n)]
    else:
        grid = list(np.linspace(f.lo, f.hi, n))
    return [float(g) for g in grid]


def effective_n(res: np.ndarray, n_signals: int) -> float:
    """n*(1 - rho)/(1 + rho) with rho the mean lag-1 autocorrelation of each signal's
    residual (AR(1)); at least 10."""
    rhos = []
    for r in np.split(res, n_signals):
        r = r - r.mean()
        den = float(np.dot(r, r))
        rhos.append(float(np.dot(r[1:], r[:-1])) / den if den > 0 else 0.0)
    rho = min(max(float(np.mean(rhos)), 0.0), 0.999)
    return max(10.0, len(res) * (1.0 - rho) / (1.0 + rho))


def fit(problem: Problem, faults: Sequence[str], free: Sequence[str],
         recorded: Mapping[str, np.ndarray] | None = None,
         starts: Sequence[Sequence[float]] | None = None, onset: float | None = None):
    """Least squares over the faults' severities + nuisance factors; returns (x, residuals,
    jacobian). ``starts``: candidate start points, the best of which is refined (default: a
    coarse grid of a single fault's severity, nuisance at design values). ``onset``: the
    (single) fault begins at this run time [s] instead of from the start."""
    from scipy.optimize import least_squares
    specs = [FAULTS[f] for f in faults]
    nf = len(specs)
    lo = [f.lo for f in specs] + [free_bounds(k)[0] for k in free]
    hi = [f.hi for f in specs] + [free_bounds(k)[1] for k in free]

    def to_run(x):
        fr = {k: float(v) for k, v in zip(free, x[nf:])}
        if onset is not None:
            return problem.params((), [], fr), ((onset, faults[0], float(x[0])),)
        return problem.params(faults, [float(v) for v in x[:nf]], fr), ()

    def fun(x):
        return problem.residuals(problem.run(*to_run(x)), recorded)

    if onset is not None and nf != 1:
        raise ValueError('an onset is fitted for one fault')
    if not lo:                                   # healthy, nothing free: no fit to make
        return np.zeros(0), fun(np.zeros(0)), np.zeros((len(problem.rows) * 3, 0))
    if starts is None:
        design = [free_start(k) for k in free]
        starts = [[g] + design for g in start_grid(faults[0])] if nf == 1 else [
            [FAULTS[f].healthy for f in faults] + design]
    starts = [np.clip(np.asarray(x, dtype=float), lo, hi) for x in starts]
    costs = None
    if len(starts) > 1:
        problem.run_many([to_run(x) for x in starts])
        costs = [float(np.sum(fun(x) ** 2)) for x in starts]
        x0 = starts[int(np.argmin(costs))]
    else:
        x0 = starts[0]
    scale = [(h - l) / 10.0 for l, h in zip(lo, hi)]

    def solve(x_start, diff_step=1e-3):
        return least_squares(fun, x_start, bounds=(lo, hi), x_scale=scale, diff_step=diff_step,
                             method='trf', xtol=1e-6, ftol=1e-8, max_nfev=60 * max(1, nf),
                             workers=problem.fleet_map(to_run))

    sol = solve(x0)
    if nf == 1 and costs is not None and not np.any(sol.jac[:, 0]):
        # the cost does not move with the severity at the fit (a finite difference sees a flat
        # stretch: static friction the jack never breaks away from), so the solver stopped
        # where it began, on a grid point; the cost may still have a valley between grid
        # points (static friction of 6 x on the built-in test: the cost 11 069 from 5.6 x up,
        # 7 369 at 4.7 x, the valley 10 % wide), so search the flat stretch finely
        x1 = _flat_stretch_minimum(problem, faults[0], fun, to_run, starts, costs, sol.x,
                                   float(np.sum(sol.fun ** 2)))
        if x1 is not None:
            sol = solve(x1)
    if nf and sol.status == 3 and sol.njev <= STALLED_JACOBIANS:
        # the step fell below its tolerance after hardly a Jacobian: the trust region shrank
        # because the cost is rough at the finite difference's scale (the friction's
        # switching), not because the fit is done -- a dynamic friction of 1.86 x on the paper
        # flight stopped at 1.78 x with CJ still at its start, RSS 2660, where 2.20 x at CJ
        # 0.72 leaves 2416; solved again from there with a coarser step it reaches the valley
        again = solve(sol.x, ROUGH_STEP)
        if np.sum(again.fun ** 2) < np.sum(sol.fun ** 2):
            sol = again
    return sol.x, sol.fun, sol.jac


#: a solve that stops on its step tolerance after at most this many Jacobians has stalled
STALLED_JACOBIANS = 2
#: the relative finite-difference step of a second solve from a stalled one (1e-3 at first:
#: 9 of 294 fits stall, none of them a right hypothesis's; measured)
ROUGH_STEP = 1e-2


#: how close to the best start's cost a start grid's point counts as on its flat stretch
FLAT_COST = 5e-3
#: the step of the search across a flat stretch: 6 % of a multiplier (the valley of static
#: friction on the built-in test is 10 % wide), 1/64 of a fraction's or a value's range
FLAT_RATIO, FLAT_SPLIT = 1.06, 64


def _flat_stretch_minimum(problem, fault, fun, to_run, starts, costs, x, rss):
    """A better severity than ``x``'s on the start grid's flat stretch around the best start
    (the grid points within :data:`FLAT_COST` of its cost), searched from the grid point
    below the stretch to the one above it in steps of :data:`FLAT_RATIO` (a multiplier) or
    :data:`FLAT_SPLIT` of the range, the nuisance held at ``x``; None when the best start has
    no flat neighbour (a bound, not a stretch) or no point is better than ``x``'s ``rss``. A
    stretch from the healthy severity on is where the fault has no effect yet: searched from
    its far end only."""
    spec = FAULTS[fault]
    sev = np.array([s[0] for s in starts])
    order = np.argsort(sev)
    sev, cost = sev[order], np.asarray(costs)[order]
    best = int(np.argmin(cost))
    flat = np.abs(cost - cost[best]) <= FLAT_COST * cost[best]
    a = b = best
    while a > 0 and flat[a - 1]:
        a -= 1
    while b < len(sev) - 1 and flat[b + 1]:
        b += 1
    if a == b:
        return None
    lo_s = sev[b] if sev[a] == spec.healthy else sev[max(a - 1, 0)]
    hi_s = sev[min(b + 1, len(sev) - 1)]
    if spec.kind == 'scale':
        n = int(np.clip(math.ceil(math.log(hi_s / lo_s) / math.log(FLAT_RATIO)), 4, 96)) + 1
        grid = np.geomspace(lo_s, hi_s, n)
    else:
        n = int(np.clip(math.ceil((hi_s - lo_s) / (spec.hi - spec.lo) * FLAT_SPLIT), 4, 96)) + 1
        grid = np.linspace(lo_s, hi_s, n)
    tries = [np.concatenate(([g], x[1:])) for g in grid]
    problem.run_many([to_run(t) for t in tries])
    tcost = [float(np.sum(fun(t) ** 2)) for t in tries]
    i = int(np.argmin(tcost))
    return tries[i] if tcost[i] < rss else None


__all__ = ['Problem', 'Point', 'fit', 'effective_n', 'start_grid', 'free_bounds', 'free_start',
           'SENSOR_BIAS', 'FREEABLE_BIAS', 'BIAS_BOUNDS', 'RESIDUAL_SCALE', 'FREE_BOUNDS',
           'CHI2_95', 'SIGNALS']
