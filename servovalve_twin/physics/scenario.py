"""Scenarios: the command Com, the external load FR and the supply pressure PSR as functions of
simulated time, loaded from YAML with every key checked.

Schema (unknown keys are an error; times in s, Com in m, FR in N, PSR in Pa)::

    name: my_run                                      # optional
    description: free text                            # optional
    duration: 1.0                                     # s, a whole number of ms (default 1.0)
    com: [[0.0, 0.02], [0.30, 0.03]]                  # steps: [t, value], held until the next
    fr:  {ramp: [[0.0, 0.0], [0.5, 5000.0]]}          # linear between points, held at the ends
    psr: {sine: {offset: 20.0e+6, amplitude: 1.0e+6, frequency: 2.0, phase: 0.0, start: 0.0}}
    params: {CLk: 2.0e-12}                            # parameter overrides (optional)
    windows: {drop: [0.35, 0.45]}                     # named analysis windows (optional)
    sensors: {seed: 7, xj: {noise: 2.0e-6}}           # the unit's sensors (optional;
                                                      # physics/sensors.py)

Files and built-in names are read by :mod:`servovalve_twin.config`. A missing signal takes its
default (Com 0 m, FR 0 N, PSR = 20 MPa), so ``{}`` is a valid
scenario. Breakpoints apply to every integration step whose start, in integer nanoseconds, is at
or after them (doc/design/MODELS.md section 9): 1.0/1e-5 is not an integer in floating point.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import threading
from typing import Any, Mapping

import numpy as np

from ..errors import ScenarioError
from .values import number as _number, short as _short
from .signals import INPUTS

SIGNALS = INPUTS
SIGNAL_UNITS = {'com': 'm', 'fr': 'N', 'psr': 'Pa'}
_DEFAULT_VALUE = {'com': 0.0, 'fr': 0.0, 'psr': 20.0e6}
_KEYS = ({'name', 'description', 'duration', 'params', 'windows', 'faults', 'sensors'}
         | set(SIGNALS))
_SINE_KEYS = {'offset', 'amplitude', 'frequency', 'phase', 'start'}
_MAX_DURATION = 3600.0
#: the most breakpoints of one signal (a scenario file, at most 1 MB, holds fewer)
MAX_BREAKPOINTS = 100_000
#: the supply-return pressure the models accept: PSRN's upper bound
_PSR_MAX = 1.0e8
#: the values an input may take: a command within +-1 m (strokes are tens of mm), a load
#: within +-10 MN (a jack of 1.2e-3 m^2 at 28 MPa pushes 34 kN), a supply within [0, PSRN's
#: bound]. Beyond, a run is arithmetic on absurd numbers (a command of 1e308 m ran, rc 0)
SIGNAL_RANGE = {'com': (-1.0, 1.0), 'fr': (-1.0e7, 1.0e7), 'psr': (0.0, _PSR_MAX)}


def _check_range(signal: str, where: str, lo: float, hi: float) -> None:
    """Refuse an input whose values span [lo, hi] beyond :data:`SIGNAL_RANGE`."""
    a, b = SIGNAL_RANGE[signal]
    if not (a <= lo and hi <= b):
        bad = lo if lo < a else hi
        raise ScenarioError(f'{where}: {signal.upper()} = {bad:g} {SIGNAL_UNITS[signal]} is '
                            f'outside [{a:g}, {b:g}] {SIGNAL_UNITS[signal]}')


def _ns(t: float) -> int:
    return int(round(t * 1e9))


#: grids a profile keeps (:meth:`Profile.grid`): a run of up to this many chunks of
#: :data:`~.simulate.CHUNK_STEPS` (2.6 s at DT = 1e-5 s) finds every chunk's inputs there on
#: its next run; at most 2 MB a profile
GRID_CACHE = 4
_GRID_LOCK = threading.Lock()


class GridBuffers:
    """Reusable buffers for :meth:`Profile.grid`: a chunk's times (computed once per chunk,
    only if some signal needs them) and a values row per input signal. :meth:`reused` hands
    a thread the same ones run after run: fresh 0.5 MB arrays each run cost their page faults
    (0.4-0.8 ms of a 1.8 ms C2 run)."""

    _local = threading.local()

    def __init__(self, size: int):
        self.size = size
        self._steps = np.arange(size, dtype=np.int64)
        self._t_ns = np.empty(size, dtype=np.int64)
        self._values = np.empty((len(SIGNALS), size))
        self._key: tuple[int, int, int] | None = None

    @classmethod
    def reused(cls, size: int) -> 'GridBuffers':
        """This thread's buffers, at least ``size`` long (what one thread's run reads from
        them is consumed before its next chunk asks for them again)."""
        buffers = getattr(cls._local, 'buffers', None)
        if buffers is None or buffers.size < size:
            buffers = cls._local.buffers = cls(size)
        return buffers

    def times(self, t0_ns: int, step_ns: int, n: int) -> np.ndarray:
        if self._key != (t0_ns, step_ns, n):
            t_ns = np.multiply(self._steps[:n], step_ns, out=self._t_ns[:n])
            t_ns += t0_ns
            self._key = (t0_ns, step_ns, n)
        return self._t_ns[:n]

    def values(self, slot: int) -> np.ndarray:
        """The values row of input ``slot`` (its index in :data:`SIGNALS`) for the grid of
        the last :meth:`times`."""
        return self._values[slot, :self._key[2]]


@dataclasses.dataclass(frozen=True)
class Profile:
    """One input signal: ``kind`` is 'steps', 'ramp' or 'sine'."""

    kind: str
    points: tuple[tuple[float, float], ...] = ()
    sine: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def values(self, t_ns: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The signal at the integer-nanosecond times ``t_ns`` (ascending), into ``out`` if
        given (simulate() reuses one buffer per signal for all its chunks)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        if out is None:
            out = np.empty(t_ns.shape)
        if self.kind == 'steps':
            # piecewise constant: the value in force at t is that of the last breakpoint <= t,
            # filled segment by segment between the breakpoints, not looked up per sample
            bp_all, vals_all = self._step_arrays
            if t_ns.shape[0] == 0:
                return out
            # only the breakpoints inside the window [t_ns[0], t_ns[-1]] and the one in force
            # at its start: a chunk's cost must not grow with the run's breakpoints (a 3600 s
            # run with 28 800 of them spent 7.8 s on inputs looking all of them up per chunk)
            lo = max(int(np.searchsorted(bp_all, t_ns[0], side='right')) - 1, 0)
            hi = int(np.searchsorted(bp_all, t_ns[-1], side='right'))
            bp, vals = bp_all[lo:hi], vals_all[lo:hi]
            cuts = np.searchsorted(t_ns, bp, side='left')
            out[:cuts[0]] = vals_all[-1]               # before the first point (never: it is 0)
            if len(vals) > 64:
                # many steps (a recorded run's 1 ms inputs): each value repeated over its
                # samples in one call (a diagnosis runs the model a hundred times on them)
                out[cuts[0]:] = np.repeat(vals, np.diff(cuts, append=t_ns.shape[0]))
                return out
            for v, a, b in zip(vals.tolist(), cuts, list(cuts[1:]) + [t_ns.shape[0]]):
                out[a:b] = v
            return out
        if self.kind == 'ramp':
            ts, vals = self._ramp_arrays
            out[:] = np.interp(t_ns * 1e-9, ts, vals)
            return out
        offset, amplitude, frequency, phase, start = self.sine
        t = (t_ns - _ns(start)) * 1e-9
        wave = offset + amplitude * np.sin(2.0 * math.pi * frequency * t + phase)
        out[:] = np.where(t >= 0.0, wave, offset)
        return out

    def grid(self, t0_ns: int, step_ns: int, n: int, buffers: GridBuffers | None = None,
             slot: int = 0) -> np.ndarray:
        """The signal at ``t0_ns + k*step_ns`` for k < ``n``. A grid asked for a second time is
        kept (the last :data:`GRID_CACHE` of them): a fit runs its model hundreds of times on
        one scenario, and evaluating the recorded 1 ms inputs as steps took 0.23 s of a 2.2 s
        diagnosis. The first time it is computed into row ``slot`` of ``buffers`` (reused
        run after run: :meth:`GridBuffers.reused`) and only noted: a scenario run once must
        not pay for fresh arrays. What is returned may be shared between callers, or
        overwritten by the next grid computed in ``buffers``: read it at once, never write
        it."""
        key = (int(t0_ns), int(step_ns), int(n))
        with _GRID_LOCK:        # threads may run one scenario at once (a lock costs ~0.1 us)
            kept, seen = self.__dict__.get('_grids') or self._new_grids()
            arr = kept.get(key)
            if arr is not None:
                kept.move_to_end(key)
                return arr
            first = key not in seen
            if first:
                seen[key] = None
                while len(seen) > GRID_CACHE:
                    seen.popitem(last=False)
            else:
                del seen[key]
        buffers = buffers or GridBuffers(key[2])
        t_ns = buffers.times(*key)
        if first:
            return self.values(t_ns, buffers.values(slot))
        arr = self.values(t_ns)
        with _GRID_LOCK:
            kept[key] = arr
            while len(kept) > GRID_CACHE:
                kept.popitem(last=False)
        return arr

    def _new_grids(self) -> tuple[collections.OrderedDict, collections.OrderedDict]:
        grids = (collections.OrderedDict(), collections.OrderedDict())   # kept, seen once
        object.__setattr__(self, '_grids', grids)                        # frozen: not a field
        return grids

    @functools.cached_property
    def _step_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Breakpoints [ns] and values as arrays, built once (not per chunk)."""
        return (np.array([_ns(t) for t, _ in self.points], dtype=np.int64),
                np.array([v for _, v in self.points]))

    @functools.cached_property
    def _ramp_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Ramp times [s] and values as arrays, built once (not per chunk)."""
        return (np.array([t for t, _ in self.points]), np.array([v for _, v in self.points]))

    def value(self, t_ns: int) -> float:
        return float(self.values(np.array([t_ns]))[0])

    def breakpoints(self) -> list[float]:
        """Times where the signal changes regime (phase boundaries for comparisons)."""
        if self.kind == 'sine':
            return [self.sine[4]] if self.sine[4] > 0 else []
        return [t for t, _ in self.points if t > 0]

    def to_yaml(self) -> Any:
        if self.kind == 'steps':
            return [list(p) for p in self.points]
        if self.kind == 'ramp':
            return {'ramp': [list(p) for p in self.points]}
        return {'sine': dict(zip(('offset', 'amplitude', 'frequency', 'phase', 'start'),
                                 self.sine))}


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A complete run description: inputs, duration, parameter overrides, analysis windows."""

    name: str
    duration: float
    com: Profile
    fr: Profile
    psr: Profile
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    windows: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    description: str = ''
    faults: tuple[Mapping[str, Any], ...] = ()      # raw fault entries, see physics.faults
    sensors: Any = None                 # a .sensors.Sensors, or None: ideal sensors

    def fault_events(self, nominal) -> list:
        """The scheduled faults resolved against ``nominal`` parameters (sorted by time)."""
        from .faults import events_from_raw
        return events_from_raw(self.faults, nominal, self.duration)

    def without_faults(self) -> 'Scenario':
        return dataclasses.replace(self, faults=())

    def with_sensor_seed(self, seed: int) -> 'Scenario':
        """The scenario with its sensors' noise realisation ``seed``; refused for a scenario
        without sensors (a seed of nothing: a mistake, not the ideal run)."""
        from ..errors import ParameterError
        if not self.sensors:
            raise ParameterError(f'sensor_seed: the scenario {self.name!r} declares no sensors '
                                 '(add a sensors: section, physics/sensors.py)')
        return dataclasses.replace(self, sensors=self.sensors.with_seed(seed))

    def without_sensors(self) -> 'Scenario':
        """The scenario measured by ideal sensors: what a model fitted to a unit's readings
        simulates (it must not know the unit's noise realisation)."""
        return dataclasses.replace(self, sensors=None)

    @property
    def duration_ns(self) -> int:
        return _ns(self.duration)

    def inputs(self, t_ns: np.ndarray, out: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Com, FR, PSR) at the integer-nanosecond times ``t_ns``; into the rows of ``out``
        (shape (3, len(t_ns))) if given."""
        if out is None:
            return self.com.values(t_ns), self.fr.values(t_ns), self.psr.values(t_ns)
        return tuple(getattr(self, s).values(t_ns, out[i]) for i, s in enumerate(SIGNALS))

    def grid_inputs(self, t0_ns: int, step_ns: int, n: int,
                    buffers: GridBuffers | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Com, FR, PSR) at ``t0_ns + k*step_ns``, k < ``n`` (:meth:`Profile.grid`: read
        them at once, never write them)."""
        return tuple(getattr(self, s).grid(t0_ns, step_ns, n, buffers, i)
                     for i, s in enumerate(SIGNALS))

    def phases(self) -> list[tuple[float, float]]:
        """The run split at every breakpoint of every signal: [(t0, t1), ...]."""
        cuts = sorted({0.0, self.duration, *[t for s in SIGNALS
                                               for t in getattr(self, s).breakpoints()
                                               if t < self.duration]})
        return list(zip(cuts[:-1], cuts[1:]))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(name=self.name, duration=self.duration)
        if self.description:
            out['description'] = self.description
        for s in SIGNALS:
            out[s] = getattr(self, s).to_yaml()
        if self.params:
            out['params'] = dict(self.params)
        if self.windows:
            out['windows'] = {k: list(v) for k, v in self.windows.items()}
        if self.faults:
            out['faults'] = [dict(f) for f in self.faults]
        if self.sensors:
            out['sensors'] = self.sensors.to_dict()
        return out


def _profile(raw: Any, signal: str, duration: float) -> Profile:
    where = f'scenario.{signal}'
    if raw is None:
        return Profile('steps', ((0.0, _DEFAULT_VALUE[signal]),))
    kind = 'steps'
    if isinstance(raw, Mapping):
        if len(raw) != 1 or next(iter(raw)) not in ('steps', 'ramp', 'sine'):
            raise ScenarioError(f'{where}: expected a list of [t, value] breakpoints or one of '
                                f"{{steps: ...}}, {{ramp: ...}}, {{sine: ...}}; got keys "
                                f'{sorted(map(str, raw))}')
        kind, raw = next(iter(raw.items()))
        where = f'{where}.{kind}'
    if kind == 'sine':
        if not isinstance(raw, Mapping):
            raise ScenarioError(f'{where}: expected a mapping with keys {sorted(_SINE_KEYS)}')
        unknown = set(raw) - _SINE_KEYS
        if unknown:
            raise ScenarioError(f'{where}: unknown key {sorted(unknown)[0]!r}; allowed '
                                f'{sorted(_SINE_KEYS)}')
        vals = tuple(_number(raw.get(k, 0.0), f'{where}.{k}')
                     for k in ('offset', 'amplitude', 'frequency', 'phase', 'start'))
        if vals[2] < 0:
            raise ScenarioError(f'{where}.frequency must be >= 0 Hz, got {vals[2]}')
        _check_range(signal, where, vals[0] - abs(vals[1]), vals[0] + abs(vals[1]))
        return Profile('sine', sine=vals)
    if not isinstance(raw, (list, tuple)) or not raw:
        raise ScenarioError(f'{where}: expected a non-empty list of [t, value] breakpoints, '
                            f'got {_short(raw)}')
    if len(raw) > MAX_BREAKPOINTS:
        # (a bag's provenance is not bounded as a scenario file is: 10^6 breakpoints took
        # longer than 90 s to read)
        raise ScenarioError(f'{where}: {len(raw)} breakpoints; at most {MAX_BREAKPOINTS}')
    points = []
    for i, item in enumerate(raw):
        if not isinstance(item, (list, tuple)) or len(item) != 2:
            raise ScenarioError(f'{where}[{i}]: expected [t, value], got {_short(item)}')
        points.append((_number(item[0], f'{where}[{i}] time'),
                       _number(item[1], f'{where}[{i}] value')))
    times = [t for t, _ in points]
    if points[0][0] != 0.0:
        raise ScenarioError(f'{where}: the first breakpoint must be at t = 0, got {times[0]}')
    bad = next((i for i, (a, b) in enumerate(zip(times, times[1:])) if b <= a), None)
    if bad is not None:
        raise ScenarioError(f'{where}: breakpoint times must increase strictly, got '
                            f'{times[bad]} then {times[bad + 1]} (breakpoints {bad} and '
                            f'{bad + 1})')
    if times[-1] > duration:
        raise ScenarioError(f'{where}: breakpoint at t = {times[-1]} s lies after the duration '
                            f'{duration} s')
    values = [v for _, v in points]
    _check_range(signal, where, min(values), max(values))
    return Profile(kind, tuple(points))


def scenario_from_dict(raw: Mapping[str, Any], name: str = 'scenario') -> Scenario:
    """Validate a scenario mapping (as read from YAML) into a :class:`Scenario`."""
    if raw is None:
        raw = {}
    if not isinstance(raw, Mapping):
        raise ScenarioError(f'a scenario must be a mapping with keys {sorted(_KEYS)}, '
                            f'got {type(raw).__name__}')
    unknown = set(raw) - _KEYS
    if unknown:
        raise ScenarioError(f'unknown scenario key {sorted(map(str, unknown))[0]!r}; allowed '
                            f'{sorted(_KEYS)}')
    duration = _number(raw.get('duration', 1.0), 'scenario.duration')
    if not 0.0 < duration <= _MAX_DURATION:
        raise ScenarioError(f'scenario.duration must be in (0, {_MAX_DURATION:g}] s, '
                            f'got {duration}')
    if _ns(duration) % 1_000_000:
        raise ScenarioError(f'scenario.duration must be a whole number of milliseconds (output '
                            f'rows are 1 ms apart), got {duration}')
    profiles = {s: _profile(raw.get(s), s, duration) for s in SIGNALS}
    params = raw.get('params') or {}
    if not isinstance(params, Mapping):
        raise ScenarioError('scenario.params must be a mapping NAME: value, got '
                            f'{_short(params)}')
    from .params import ParameterError, coerce, make_params
    try:
        params = {str(k): coerce(str(k), v) for k, v in params.items()}
        make_params(params)     # range and cross checks now, not at run time
    except ParameterError as exc:
        raise ScenarioError(f'scenario.params: {exc}') from None
    windows = {}
    raw_windows = raw.get('windows') or {}
    if not isinstance(raw_windows, Mapping):
        raise ScenarioError(f'scenario.windows: expected a mapping NAME: [t0, t1], got '
                            f'{_short(raw_windows)}')
    for wname, span in raw_windows.items():
        if not isinstance(span, (list, tuple)) or len(span) != 2:
            raise ScenarioError(f'scenario.windows.{wname}: expected [t0, t1], got '
                                f'{_short(span)}')
        t0, t1 = (_number(v, f'scenario.windows.{wname}') for v in span)
        if not 0.0 <= t0 < t1 <= duration:
            raise ScenarioError(f'scenario.windows.{wname}: need 0 <= t0 < t1 <= duration, '
                                f'got [{t0}, {t1}]')
        windows[str(wname)] = (t0, t1)
    faults = raw.get('faults') or []
    if not isinstance(faults, (list, tuple)):
        raise ScenarioError('scenario.faults: expected a list of {at, fault, severity} or '
                            '{at, param, value} entries')
    sensors = None
    if raw.get('sensors') is not None:
        from .sensors import sensors_from_dict
        sensors = sensors_from_dict(raw['sensors'])
    scenario = Scenario(name=str(raw.get('name', name)), duration=duration, params=params,
                        windows=windows, description=str(raw.get('description', '')),
                        sensors=sensors,
                        faults=tuple({str(k): _plain(v) for k, v in f.items()}
                                     if isinstance(f, Mapping) else f for f in faults),
                        **profiles)
    scenario.fault_events(make_params(params))          # validate now, with the defaults
    return scenario


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python number it holds (a scenario built in Python with numpy
    times is written into a bag's YAML provenance, which takes plain numbers only)."""
    return value.item() if isinstance(value, np.generic) else value


def as_scenario(spec: Mapping[str, Any] | Scenario) -> Scenario:
    """A :class:`Scenario` from a mapping of the schema (or as is). Names and files are read by
    :func:`servovalve_twin.config.load_scenario`: the physics reads no files."""
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    raise ScenarioError(f'expected a Scenario or a mapping, got {type(spec).__name__} '
                        f'{_short(spec)}; load names and files with servovalve_twin.config.'
                        'load_scenario')
