"""Sensors as real ones are: a seeded model per measured signal -- white Gaussian noise, a bias,
a drift, quantisation and a sample period of its own -- applied where the twin measures, so that
the ECU closes its position loop on the *measured* XJ and every published or recorded value of a
sensed signal is what its sensor read. The truth stays with the run (``RunResult.truth``).

Declared in a scenario (or given to :func:`~.simulate.simulate`, the plant node's ``sensors``
parameter, the FMU's build)::

    sensors:
      seed: 7                    # the noise realisation (an integer, default 0)
      xj:  {noise: 2.0e-6, quantisation: 1.0e-6}          # m
      p12: {noise: 5.0e+4, bias: 1.0e+4, period: 0.002}   # Pa; sampled every 2 ms
      xs:  {drift: 1.0e-6}                                # m/s

A sensor samples at the instants k*period (period: a whole number of control periods; default
the control period, or the 1 ms output period when the ECU is continuous) and its reading is held
until the next sample::

    y_k = Q(x(t_k) + bias + drift*t_k + noise*n_k),   Q(y) = q*floor(y/q + 1/2)  (q > 0)

n_k is a standard normal draw that depends only on (seed, signal, k): a counter-based generator
(SplitMix64 bits, Box-Muller), so the compiled loop, the ROS plant node and the FMU -- each
stepping on its own -- read the same values, and a run is reproducible from its seed alone.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import numpy as np

from ..errors import ScenarioError
from ..jitcache import jit
from .values import number as _number

#: the signals a sensor can measure (the plant's outputs; Com, FR, PSR are inputs, Cor the
#: ECU's own output, QJ = AJ*DXJ a model quantity no sensor reads)
SENSED = ('xs', 'xj', 'dxj', 'p12', 'p1', 'p2')
#: the state signals, read at a step's start before the ECU; the valve's, after the valve call
N_STATE = 3
FIELDS = ('noise', 'bias', 'drift', 'quantisation', 'period')
#: columns of :meth:`Sensors.table`
C_ON, C_NOISE, C_BIAS, C_DRIFT, C_QUANT, C_EVERY, C_PERIOD = range(7)
_MAX_SEED = 2 ** 63 - 1
_MASK = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
#: the longest sensor period [s] (as the ECU's: a slower sensor barely measures the loop)
MAX_PERIOD = 0.1


@dataclasses.dataclass(frozen=True)
class SensorSpec:
    """One signal's sensor: noise [unit, 1 sigma], bias [unit], drift [unit/s], quantisation
    step [unit] (0: none), sample period [s] (None: the control period)."""

    noise: float = 0.0
    bias: float = 0.0
    drift: float = 0.0
    quantisation: float = 0.0
    period: float | None = None

    def to_dict(self) -> dict[str, float]:
        return {f: getattr(self, f) for f in FIELDS
                if getattr(self, f) not in (None, 0.0)}


@dataclasses.dataclass(frozen=True)
class Sensors:
    """The sensors of one unit: a seed and a :class:`SensorSpec` per sensed signal."""

    seed: int = 0
    specs: tuple[tuple[str, SensorSpec], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.specs)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.specs)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {'seed': self.seed}
        out.update({n: s.to_dict() for n, s in self.specs})
        return out

    def with_seed(self, seed: int) -> 'Sensors':
        return dataclasses.replace(self, seed=_seed(seed, 'sensors.seed'))

    def table(self, control_steps: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The compiled code's view: a row per :data:`SENSED` signal (columns ``C_*``: on,
        noise, bias, drift, quantisation, period in DT steps, period in s) and a key per
        signal for the noise draws. ``control_steps``: DT steps per control period."""
        spec = np.zeros((len(SENSED), 7))
        spec[:, C_EVERY] = 1.0
        given = dict(self.specs)
        for j, name in enumerate(SENSED):
            s = given.get(name)
            if s is None:
                continue
            every = control_steps
            if s.period is not None:
                every = int(round(s.period / dt))
                if abs(every * dt - s.period) > 1e-9 * s.period or every % control_steps:
                    raise ScenarioError(
                        f'sensors.{name}.period = {s.period:g} s must be a whole number of '
                        f'control periods ({control_steps * dt:g} s)')
            spec[j] = (1.0, s.noise, s.bias, s.drift, s.quantisation, every, every * dt)
        keys = np.array([signal_key(self.seed, j) for j in range(len(SENSED))],
                        dtype=np.uint64)
        return spec, keys


def sensor_table(sensors: Sensors | None, control_steps: int, dt: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Sensors.table`, or for no sensors (None) the table of ideal ones: every signal
    read as it is, at every step."""
    if sensors:
        return sensors.table(control_steps, dt)
    spec = np.zeros((len(SENSED), 7))
    spec[:, C_EVERY] = 1.0
    return spec, np.zeros(len(SENSED), dtype=np.uint64)


def _seed(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ScenarioError(f'{where}: expected an integer in [0, 2**63 - 1], got {value!r}')
    if not 0 <= int(value) <= _MAX_SEED:
        raise ScenarioError(f'{where} = {value} is outside [0, 2**63 - 1]')
    return int(value)


def sensors_from_dict(raw: Any, where: str = 'scenario.sensors') -> Sensors | None:
    """Validate a ``sensors`` mapping (None, or no signal: ideal sensors); ``where`` names
    it in the error line."""
    if raw is None:
        return None
    top = where
    if not isinstance(raw, Mapping):
        raise ScenarioError(f'{top}: expected a mapping of seed and SIGNAL: '
                            f'{{{", ".join(FIELDS)}}}, got {type(raw).__name__}')
    allowed = ('seed',) + SENSED
    specs = []
    for name, entry in raw.items():
        name = str(name)
        if name not in allowed:
            raise ScenarioError(f'{top}: unknown key {name!r}; allowed seed and the '
                                f'sensed signals {list(SENSED)}')
        if name == 'seed':
            continue
        where = f'{top}.{name}'
        if not isinstance(entry, Mapping):
            raise ScenarioError(f'{where}: expected a mapping with some of {list(FIELDS)}')
        unknown = set(map(str, entry)) - set(FIELDS)
        if unknown:
            raise ScenarioError(f'{where}: unknown key {sorted(unknown)[0]!r}; allowed '
                                f'{list(FIELDS)}')
        values: dict[str, Any] = {}
        for f in FIELDS:
            if entry.get(f) is None:
                continue
            v = _number(entry[f], f'{where}.{f}')
            if f in ('noise', 'quantisation') and v < 0:
                raise ScenarioError(f'{where}.{f} must be >= 0, got {v:g}')
            if f == 'period' and not 0 < v <= MAX_PERIOD:
                raise ScenarioError(f'{where}.period must be in (0, {MAX_PERIOD:g}] s, '
                                    f'got {v:g}')
            values[f] = v
        specs.append((name, SensorSpec(**values)))
    seed = _seed(raw.get('seed', 0), f'{top}.seed')
    order = {n: i for i, n in enumerate(SENSED)}
    specs.sort(key=lambda ns: order[ns[0]])
    return Sensors(seed, tuple(specs)) if specs else None


def _mix_py(z: int) -> int:
    """SplitMix64's finaliser on Python integers: the reference of :func:`_mix`."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK
    return z ^ (z >> 31)


def signal_key(seed: int, j: int) -> int:
    """The noise key of signal ``j`` of a unit seeded ``seed``."""
    return _mix_py((seed + (j + 1) * _GOLDEN) & _MASK)


def std_normal_py(key: int, k: int) -> float:
    """Draw ``k`` of the stream ``key`` on Python integers (the reference of :func:`std_normal`,
    checked bit for bit by the tests)."""
    a = _mix_py((key + k * _GOLDEN) & _MASK)
    b = _mix_py(a ^ 0xD1B54A32D192ED03)
    u1 = ((a >> 11) + 1) * 2.0 ** -53
    u2 = (b >> 11) * 2.0 ** -53
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


_U30, _U27, _U31, _U11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_UG, _UB = np.uint64(_GOLDEN), np.uint64(0xD1B54A32D192ED03)


@jit(inline='always')
def _mix(z):
    z = (z ^ (z >> _U30)) * _M1
    z = (z ^ (z >> _U27)) * _M2
    return z ^ (z >> _U31)


@jit(inline='always')
def std_normal(key, k):
    """Draw ``k`` (>= 0) of the standard normal stream ``key`` (uint64): two SplitMix64 words
    turned into uniforms on (0, 1] and [0, 1), then Box-Muller's cosine branch."""
    a = _mix(key + np.uint64(k) * _UG)
    b = _mix(a ^ _UB)
    u1 = (float(a >> _U11) + 1.0) * 2.0 ** -53
    u2 = float(b >> _U11) * 2.0 ** -53
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@jit(inline='always')
def sense(j, x, i, spec, keys, held):
    """Signal ``j`` at step ``i`` with the true value ``x``: at a sample instant of its sensor
    the reading is taken into ``held[j]``; between samples ``held[j]`` keeps the last one. A
    signal without a sensor reads its truth at every step."""
    if spec[j, C_ON] == 0.0:
        held[j] = x
        return
    every = int(spec[j, C_EVERY])
    if i % every != 0:
        return
    k = i // every
    y = x + spec[j, C_BIAS] + spec[j, C_DRIFT] * (k * spec[j, C_PERIOD])
    if spec[j, C_NOISE] != 0.0:
        y += spec[j, C_NOISE] * std_normal(keys[j], k)
    q = spec[j, C_QUANT]
    if q > 0.0:
        y = q * math.floor(y / q + 0.5)
    held[j] = y


@jit
def sense_block(j0, values, i, spec, keys, held):
    """:func:`sense` for signals ``j0 .. j0 + len(values) - 1`` (the ROS plant's and the FMU's
    one call per tick)."""
    for m in range(values.shape[0]):
        sense(j0 + m, values[m], i, spec, keys, held)


def normal_draws(seed: int, signal: str, k: np.ndarray) -> np.ndarray:
    """The standard normal draws ``k`` of ``signal``'s sensor for ``seed`` (tests, analysis)."""
    key = signal_key(seed, SENSED.index(signal))
    return np.array([std_normal_py(key, int(i)) for i in np.asarray(k).ravel()])


__all__ = ['SENSED', 'FIELDS', 'SensorSpec', 'Sensors', 'sensors_from_dict', 'sensor_table',
           'sense',
           'sense_block', 'std_normal', 'std_normal_py', 'signal_key', 'normal_draws']
