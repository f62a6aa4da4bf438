"""Fault sweeps: many ROS-free runs (grid or Monte-Carlo) of a plant with injected faults beside
a monitor model, in parallel, into a labelled dataset for prognostics work.

One *case* = plant model + monitor model + scenario + parameter draw + (fault, severity, onset).
Each run yields one dataset row (parameters, fault label, severity, summary features, alarm,
detection delay) and, when asked for, its traces (residuals, indicators, health level per
1 ms). Cases run on a local process pool (default: one worker per core) or on an existing Dask
cluster (``scheduler='tcp://host:8786'``); the physics is the same ``simulate`` either way.

Speed (bench/bench_sweep.py): the parent loads the compiled physics once before the pool
forks, so no worker compiles; runs travel back as rows (~2 kB) unless traces are asked for
(~90 kB each); and :func:`.dataset.write_dataset` streams rows and traces to the dataset as
they arrive, so the parent never holds the traces and a stopped sweep keeps its finished runs.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from ..config import load_scenario
from ..errors import TwinError
from ..physics.faults import FAULTS
from ..physics.params import PARAM_NAMES, make_params
from ..physics.simulate import simulate
from ..progress import progress
from .parallel import map_unordered
from .monitor import (DEFAULT_MONITOR_MODEL, ERROR, WARN, HealthConfig, MonitorAlgorithm,
                      MonitorResult)


@dataclasses.dataclass(frozen=True)
class Case:
    """One run of a sweep (picklable: it crosses process and Dask boundaries)."""

    run_id: int
    plant_model: str
    monitor_model: str
    scenario: Any                      # name, path or mapping
    params: Mapping[str, float]        # this actuator's parameter values (with its nuisance draw)
    fault: str                         # 'none' for a nominal run
    severity: float
    onset: float
    ecu_period: float = 1e-3
    thresholds: Mapping[str, float] | None = None
    design: Mapping[str, float] = dataclasses.field(default_factory=dict)
    #: the design values the monitor knows (the --param overrides, without the nuisance draw):
    #: a monitor cannot know each unit's own mass or friction
    algorithm: Any = None              # a user's Algorithm ('pkg.mod:Class' or class) instead
    algorithm_params: Mapping[str, Any] | None = None      # of the monitor; its parameters


def run_case(case: Case, traces: bool = True) -> dict[str, Any]:
    """Simulate the plant (fault from ``onset``) and the monitor: ``{'row': features, 'traces':
    arrays}`` (``traces`` empty unless asked for)."""
    scn = load_scenario(case.scenario)
    raw = scn.to_dict()
    raw.pop('params', None)          # folded into ``nominal`` below, with this draw on top
    if case.fault != 'none':
        raw['faults'] = list(raw.get('faults', [])) + [
            {'at': case.onset, 'fault': case.fault, 'severity': case.severity}]
    actual = make_params(dict(scn.params) | dict(case.params))
    design = make_params(dict(scn.params) | dict(case.design))
    # a scenario's sensors: each run is a unit of its own, with its own noise realisation
    seed = None if scn.sensors is None else (scn.sensors.seed + case.run_id) % 2 ** 63
    run = simulate(case.plant_model, raw, params=actual, ecu_period=case.ecu_period,
                   sensor_seed=seed)
    features, trace_arrays, alarm, warn = _algorithm_case(case, run, design)
    before = alarm is not None and alarm < case.onset
    row: dict[str, Any] = dict(
        run_id=case.run_id, plant_model=case.plant_model, monitor_model=case.monitor_model,
        scenario=scn.name, fault=case.fault, severity=case.severity,
        onset=case.onset if case.fault != 'none' else float('nan'),
        faulty=int(case.fault != 'none'), alarm=int(alarm is not None),
        alarm_time=float('nan') if alarm is None else alarm,
        warn_time=float('nan') if warn is None else warn,
        detection_delay=(alarm - case.onset) if (alarm is not None and case.fault != 'none'
                                                  and alarm >= case.onset) else float('nan'),
        alarm_before_onset=int(bool(before)))
    row.update({f'param_{k}': float(v) for k, v in case.params.items()})
    row.update(features)
    return dict(row=row, traces=trace_arrays if traces else {})


def _algorithm_case(case: Case, run, design):
    """The monitor, or the user's algorithm, on the run's 1 ms rows -- the ticks the twin's
    lockstep feeds it live at a 1 ms control period (the twin equals simulate with that ECU
    period). The built-in monitor's features and traces keep their names (``peak_rms_*``,
    ``res_*``, ``ind_*``); an algorithm's are named after its outputs."""
    from ..physics.simulate import OUTPUT_PERIOD_NS
    from .algorithm import load_algorithm, run_algorithm
    if int(round(case.ecu_period * 1e9)) != OUTPUT_PERIOD_NS:
        raise TwinError('the monitor or an algorithm in a sweep runs at the 1 ms control '
                        f'period, got {case.ecu_period} s')
    if case.algorithm is None:
        alg = MonitorAlgorithm.with_config(
            case.monitor_model, HealthConfig(**case.thresholds) if case.thresholds else None)
    else:
        alg = load_algorithm(case.algorithm, case.algorithm_params)
    t_ns = np.arange(len(run['t']), dtype=np.int64) * OUTPUT_PERIOD_NS
    res = run_algorithm(alg, t_ns, run.signals, case.ecu_period, design)
    if case.algorithm is None:
        mon = MonitorResult.of(res, alg.config)
        return (mon.features(), dict(t=mon.t, level=mon.level.astype(np.int8),
                                     **{f'res_{k}': v for k, v in mon.residuals.items()},
                                     **{f'ind_{k}': v for k, v in mon.indicators.items()}),
                mon.first_alarm(ERROR), mon.first_alarm(WARN))
    features = {f'peak_{k}': float(np.max(v)) for k, v in res.outputs.items()}
    features.update({f'mean_abs_{k}': float(np.mean(np.abs(v))) for k, v in res.outputs.items()})
    features['max_level'] = int(res.level.max())
    traces = dict(t=res.t, level=res.level, **{f'out_{k}': v for k, v in res.outputs.items()})
    return features, traces, res.first(ERROR), res.first(WARN)


def draw_nuisance(rng: np.random.Generator, vary: Mapping[str, float], nominal
                  ) -> dict[str, float]:
    """One unit's parameters drawn around ``nominal``: each of ``vary`` (name -> relative
    spread) uniform within +-spread of its nominal value, in ``vary``'s order."""
    return {name: float(nominal.value(name) * (1.0 + rng.uniform(-spread, spread)))
            for name, spread in vary.items()}


def measured(signals: Mapping[str, np.ndarray], noise: Mapping[str, float],
             rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The run's signals as a sensor reads them: white Gaussian noise of ``noise`` (signal ->
    RMS, SI units) added to those signals, the others as they are."""
    out = dict(signals)
    for k, sd in noise.items():
        out[k] = out[k] + rng.normal(0.0, sd, out[k].shape)
    return out


#: the most runs one sweep may ask for (~17 min at bench_sweep's ~100 runs/s on 2 workers): a typo
#: such as --draws 1000000000 is refused before it fills the memory with cases
MAX_RUNS = 100_000


def make_cases(*, plant_model: str = 'HD', monitor_model: str = DEFAULT_MONITOR_MODEL,
               scenario: Any = 'paper', faults: Mapping[str, Sequence[float]] | None = None,
               nominal_runs: int = 1, repeats: int = 1, draws: int = 0,
               ranges: Mapping[str, tuple[float, float]] | None = None,
               vary: Mapping[str, float] | None = None, onset: float = 0.1, seed: int = 0,
               base: Mapping[str, Any] | None = None,
               thresholds: Mapping[str, float] | None = None, algorithm: Any = None,
               algorithm_params: Mapping[str, Any] | None = None) -> list[Case]:
    """A grid (``faults``: name -> severities, each run ``repeats`` times) and/or Monte-Carlo
    draws (``draws`` runs per fault in ``ranges``: name -> (lo, hi), severities uniform), plus
    ``nominal_runs`` fault-free runs. ``vary`` (name -> relative spread) draws every run's
    parameters uniformly in nominal*(1 +- spread): the nuisance a detector must tolerate."""
    from ..physics.simulate import effective_params
    for name in list(faults or {}) + list(ranges or {}):
        if name not in FAULTS:
            raise TwinError(f'unknown fault {name!r}; expected one of {sorted(FAULTS)}')
    for name in vary or {}:
        if name not in PARAM_NAMES:
            raise TwinError(f'--vary: unknown parameter {name!r}')
    scn = load_scenario(scenario)
    nominal = effective_params(scn, base)
    if not 0.0 <= onset < scn.duration:
        raise TwinError(f'onset {onset} s must lie in [0, {scn.duration}) s')
    if algorithm is not None:
        from .algorithm import load_algorithm
        load_algorithm(algorithm, algorithm_params)          # a bad class path fails now
    n_runs = (nominal_runs + repeats * sum(len(s) for s in (faults or {}).values())
              + draws * len(ranges or {}))
    if not 1 <= n_runs <= MAX_RUNS:
        raise TwinError(f'a sweep runs 1 to {MAX_RUNS} runs, these options ask for {n_runs} '
                        '(fault severities x repeats + ranges x draws + nominal runs)')
    for name, (lo, hi) in (ranges or {}).items():
        FAULTS[name].value(nominal, lo)                 # both ends in the catalog's bounds
        FAULTS[name].value(nominal, hi)
    rng = np.random.default_rng(seed)
    cases: list[Case] = []

    def draw_params() -> dict[str, float]:
        p = {k: float(v) for k, v in (base or {}).items()}
        p.update(draw_nuisance(rng, vary or {}, nominal))
        make_params(p, base=nominal)                      # validate the draw
        return p

    def add(fault: str, severity: float) -> None:
        cases.append(Case(run_id=len(cases), plant_model=plant_model,
                          monitor_model=monitor_model, scenario=scn.to_dict(),
                          params=draw_params(), fault=fault, severity=float(severity),
                          onset=onset, thresholds=thresholds,
                          design={k: v for k, v in (base or {}).items()},
                          algorithm=algorithm, algorithm_params=algorithm_params))
    for _ in range(nominal_runs):
        add('none', 0.0)
    for name, severities in (faults or {}).items():
        for sev in severities:
            FAULTS[name].value(nominal, float(sev))        # range check now
            for _ in range(repeats):
                add(name, sev)
    for name, (lo, hi) in (ranges or {}).items():
        for _ in range(draws):
            add(name, rng.uniform(lo, hi))
    return cases


def run_cases(cases: Sequence[Case], *, workers: int | None = None,
              scheduler: str | None = None, traces: bool = True) -> list[dict[str, Any]]:
    """Every case's result, in case order (:func:`iter_results` collected)."""
    return sorted(iter_results(cases, workers=workers, scheduler=scheduler, traces=traces),
                  key=lambda r: r['row']['run_id'])


#: runs per Dask task: a run of ~20 ms costs ~15 ms of Dask's own CPU per task
DASK_BATCH = 16


def iter_results(cases: Sequence[Case], *, workers: int | None = None,
                 scheduler: str | None = None, traces: bool = True
                 ) -> Iterator[dict[str, Any]]:
    """Run every case and yield the results as the runs finish (each row carries its
    ``run_id``): on a Dask cluster when ``scheduler`` is its address (in tasks of
    :data:`DASK_BATCH` runs), else on a local process pool of ``workers`` (default: the number
    of cores) -- :func:`.parallel.map_unordered`. ``traces`` = False returns rows only (what
    a dataset needs). Closing the stream early (Ctrl-C in the consumer) cancels the runs not
    started; the pool's workers ignore SIGINT, so that the parent alone decides."""
    cases = list(cases)
    run = functools.partial(run_case, traces=traces)
    if scheduler:
        yield from progress(map_unordered(run, cases, scheduler=scheduler, batch=DASK_BATCH),
                            total=len(cases), desc='sweep', unit='run')
        return
    workers = workers or os.cpu_count() or 1
    if workers == 1 or len(cases) <= 1:
        yield from progress(map(run, cases), total=len(cases), desc='sweep', unit='run')
        return
    # the first case runs here: it loads (or compiles) the physics of this plant and monitor
    # in the parent, which the forked workers then share instead of each loading its own
    yield run(cases[0])
    yield from progress(map_unordered(run, cases[1:], workers=workers),
                        total=len(cases), initial=1, desc='sweep', unit='run')


def parse_fault_specs(items: list[str]) -> tuple[dict[str, list[float]], dict[str, tuple]]:
    """``sweep --fault`` items: ``NAME:S1,S2,...`` (a grid) or ``NAME:LO~HI`` (a range for
    Monte-Carlo draws), as (grid, ranges)."""
    grid: dict[str, list[float]] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, spec = item.partition(':')
        try:
            if not sep:
                raise ValueError
            if '~' in spec:
                lo, hi = (float(v) for v in spec.split('~'))
                if not lo < hi:
                    raise TwinError(f'--fault {item}: the range LO~HI needs LO < HI')
                values = [lo, hi]
                ranges[name] = (lo, hi)
            else:
                values = grid[name] = [float(v) for v in spec.split(',') if v.strip()]
            if not values or not all(math.isfinite(v) for v in values):
                raise ValueError
        except ValueError:
            raise TwinError(f'--fault expects NAME:S1,S2,... (grid) or NAME:LO~HI (with '
                            f'--draws) of finite severities, got {item!r}') from None
    return grid, ranges


def parse_vary(items: list[str]) -> dict[str, float]:
    """``sweep --vary PARAM=SPREAD`` items (0 <= SPREAD < 1, relative) as {param: spread}."""
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        try:
            if not sep:
                raise ValueError
            out[name] = float(value)
            if not 0.0 <= out[name] < 1.0:
                raise ValueError
        except ValueError:
            raise TwinError(f'--vary expects PARAM=SPREAD with 0 <= SPREAD < 1, got {item!r}'
                            ) from None
    return out
