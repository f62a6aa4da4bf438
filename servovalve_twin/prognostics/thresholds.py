"""Monitor thresholds set for a stated false-alarm rate, not by hand: healthy HD actuators,
their nuisance (M, CJ, FDJ) drawn within 1.5 x the documented spread and measured with the
documented sensor noise, fly a set of flights (:func:`monitor_cal_flights`: every built-in
scenario, chirps, seeded random steps under load); each run's peak indicator per residual is
collected, a Gumbel law (the law of maxima) is fitted to them by moments, and each threshold
is its quantile at the per-flight false-alarm rate shared among the three residuals
(:data:`FALSE_ALARM_RATE`). ``bench/calibrate_monitor.py`` packages the result as every
monitor model's defaults (:data:`.monitor.MONITOR_CALIBRATION_FILE`);
``servovalve-twin monitor-thresholds`` computes them for your own flights.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.simulate import effective_params, simulate
from .monitor import RESIDUALS, HealthConfig, monitor_run

#: per-flight false-alarm rates the thresholds are set for (shared among the residuals)
FALSE_ALARM_RATE = {'warn': 1e-2, 'error': 1e-3}


def chirp(f0: float, f1: float, amplitude: float, duration: float, load: float
          ) -> dict[str, Any]:
    """A linear chirp f0 -> f1 [Hz] of Com as a ramp profile sampled every 2 ms."""
    t = np.arange(0.0, duration + 1e-9, 2e-3)
    phase = 2 * math.pi * (f0 * t + (f1 - f0) * t * t / (2 * duration))
    return dict(name=f'chirp_{f0:g}_{f1:g}', duration=duration,
                com={'ramp': [[round(float(a), 6), float(amplitude * math.sin(b))]
                              for a, b in zip(t, phase)]},
                fr=[[0.0, 0.0], [0.01, load]])


def random_steps(seed: int, duration: float = 2.0, stroke: float = 0.04,
                 load: float = 6000.0, n: int = 8) -> dict[str, Any]:
    """Seeded random steps of Com and FR (uniform levels and instants)."""
    rng = np.random.default_rng(seed)
    tc = np.sort(rng.uniform(0.02, duration - 0.1, n))
    tf = np.sort(rng.uniform(0.0, duration - 0.1, n // 2))
    return dict(name=f'steps_{seed}', duration=duration,
                com=[[0.0, 0.0]] + [[round(float(t), 3), float(rng.uniform(-stroke, stroke))]
                                    for t in tc],
                fr=[[0.0, 0.0]] + [[round(float(t), 3), float(rng.uniform(-load, load))]
                                   for t in tf])


def monitor_cal_flights() -> dict[str, Any]:
    """The calibration flights: every built-in scenario, two chirps, three random steps."""
    from ..config import builtin_scenarios
    flights: dict[str, Any] = {n: n for n in builtin_scenarios()}
    for f0, f1, amp, load in ((0.5, 10.0, 0.02, 0.0), (1.0, 20.0, 0.01, 5000.0)):
        c = chirp(f0, f1, amp, 2.0, load)
        flights[c['name']] = c
    for seed in (1, 2, 3):
        flights[f'steps_{seed}'] = random_steps(seed)
    return flights


def _measured_unit(flown, design_scenario, rng: np.random.Generator, spread: float):
    """One HD unit flying ``flown`` (a Scenario): its nuisance drawn within ``spread`` x the
    documented spread, the scenario's parameters of ``design_scenario`` on it, 1 ms ECU,
    measured with the documented noise -- rng consumed in that order."""
    from ..physics.params import DEFAULTS
    from .calibration_set import NOISE, VARY
    from .sweep import draw_nuisance, measured
    unit = DEFAULTS.replace(**draw_nuisance(rng, {k: v * spread for k, v in VARY.items()},
                                            DEFAULTS))
    run = simulate('HD', flown, params=effective_params(design_scenario, None, unit),
                   ecu_period=1e-3)
    return dataclasses.replace(run, signals=measured(run.signals, NOISE, rng))


def healthy_peaks(models: Sequence[str], flights: Mapping[str, Any], units: int, seed: int,
                  *, spread: float = 1.5, window: float = 0.05
                  ) -> dict[str, dict[str, list[float]]]:
    """Per monitor model and residual, the peak indicator of each healthy HD unit's run
    (``units`` per flight, nuisance within ``spread`` x the documented spread, documented
    noise), the monitor stepped as it runs live; each HD run serves every model."""
    from ..config import load_scenario
    rng = np.random.default_rng(seed)
    peaks = {m: {s: [] for s in RESIDUALS} for m in models}
    # thresholds play no part in the peaks: the hand-set ones serve a model not yet calibrated
    config = HealthConfig(window=window)
    for name in flights:
        scn = load_scenario(flights[name])
        design = effective_params(scn)
        for _ in range(units):
            noisy = _measured_unit(scn, scn, rng, spread)
            for m in models:
                mon = monitor_run(noisy, m, config, nominal=design)
                for s in RESIDUALS:
                    peaks[m][s].append(float(mon.indicators[s].max()))
    return peaks


def revealed(model: str, flights: Mapping[str, Any], config: HealthConfig, units: int,
             seed: int, *, spread: float = 1.5) -> dict[str, dict[str, list[int]]]:
    """What the flights reveal to the monitor at ``config``'s thresholds: per catalog fault
    and flight, the worst level (0 OK, 1 WARN, 2 ERROR) it raises on each of ``units`` HD
    units with the fault at its alarm severity from the start (nuisance within ``spread`` x
    the documented spread, documented noise; seeds of their own). Thresholds that keep
    healthy units quiet on a flight may leave a fault silent there too: a slow hold reveals
    no friction, a flight without load no leak."""
    from ..config import load_scenario
    from ..physics.faults import FAULTS
    from ..physics.scenario import scenario_from_dict
    rng = np.random.default_rng(seed)
    out: dict[str, dict[str, list[int]]] = {f: {} for f in FAULTS}
    for name in flights:
        scn = load_scenario(flights[name])
        design = effective_params(scn)
        for fault, spec in FAULTS.items():
            faulty = scenario_from_dict(dict(scn.to_dict(), faults=[
                {'at': 0.0, 'fault': fault, 'severity': spec.demo}]))
            levels = out[fault].setdefault(name, [])
            for _ in range(units):
                noisy = _measured_unit(faulty, scn, rng, spread)
                levels.append(int(monitor_run(noisy, model, config, nominal=design
                                              ).level.max()))
    return out


def format_revealed(rev: Mapping[str, Mapping[str, Sequence[int]]]) -> str:
    """The table of :func:`revealed`: per fault, ERROR (and WARN) units of each flight, and
    the faults no flight reveals with an ERROR in most units."""
    from ..physics.faults import FAULTS
    flights = list(next(iter(rev.values())))
    lines = ['what these flights reveal: units at ERROR (WARN) of those flown, each catalog '
             'fault at its alarm severity from the start']
    hidden = []
    for fault, by in rev.items():
        cells = [f'{sum(v == 2 for v in by[f])}({sum(v == 1 for v in by[f])})/{len(by[f])}'
                 for f in flights]
        lines.append(f'  {fault:24s} {FAULTS[fault].show(FAULTS[fault].demo):>14s}  '
                     + '  '.join(f'{f}: {c}' for f, c in zip(flights, cells)))
        if not any(2 * sum(v == 2 for v in by[f]) > len(by[f]) for f in flights):
            hidden.append(fault)
    if hidden:
        lines.append(f'not revealed (an ERROR in most units on no flight): {", ".join(hidden)}'
                     ' -- fly the built-in test before flight (servovalve-twin bit) or add a '
                     'flight that excites them')
    return '\n'.join(lines)


#: the fewest healthy peaks a Gumbel law is fitted to (its scale is a sample sd: one peak
#: gave thresholds of NaN)
MIN_PEAKS = 2


def gumbel_quantile(samples: Sequence[float], exceedance: float) -> float:
    """The value a maximum exceeds with probability ``exceedance``, from a Gumbel law fitted
    to ``samples`` by moments (scale sd*sqrt(6)/pi, location mean - 0.5772*scale)."""
    x = np.asarray(samples, dtype=float)
    if x.size < MIN_PEAKS or not np.all(np.isfinite(x)):
        raise TwinError(f'a Gumbel law needs at least {MIN_PEAKS} finite healthy peaks, got '
                        f'{x.size}{"" if np.all(np.isfinite(x)) else " (not all finite)"}: '
                        'fly more units or flights')
    beta = float(np.std(x, ddof=1)) * math.sqrt(6.0) / math.pi
    mu = float(np.mean(x)) - 0.5772156649 * beta
    return mu - beta * math.log(-math.log1p(-exceedance))


def calibrate_thresholds(peaks: Mapping[str, Sequence[float]], *, window: float = 0.05,
                         rates: Mapping[str, float] = FALSE_ALARM_RATE) -> dict[str, float]:
    """Thresholds for the per-flight false-alarm ``rates`` from healthy peak indicators (one
    list per residual): each residual gets a third of the rate."""
    out: dict[str, float] = {'window': window}
    for s in RESIDUALS:
        for level in ('warn', 'error'):
            q = gumbel_quantile(peaks[s], rates[level] / len(RESIDUALS))
            out[f'{level}_{s}'] = float(max(q, max(peaks[s])))
    return out
