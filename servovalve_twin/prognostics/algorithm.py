"""Your own PHM algorithm, written once and run live in the twin, on recorded bags and over fault
sweeps -- with identical results, because all three hosts call it through
:class:`AlgorithmRunner` with the same floats: one control period at a time, or a whole run
at once where the algorithm offers ``steps`` (which must give what stepping gives).

An algorithm is a plain Python class (no rclpy), in the style of progpy's models::

    from servovalve_twin.prognostics import Algorithm, Health

    class LeakDetector(Algorithm):
        inputs = ('com', 'xj', 'p12', 'fr', 'psr')    # signal names of the twin's topics
        outputs = ('leak_index',)
        parameters = {'threshold': 3.0}
        def step(self, t, u):                         # one control period
            ...
            return {'leak_index': value}
        def health(self):                             # optional
            return Health(ERROR if ... else OK, 'message')

- ``inputs``: any of :data:`SIGNALS` (the twin's Float64 topics: what the plant, ECU and
  schedules publish at the tick's time t);
- ``outputs``: names published live as ``std_msgs/Float64`` on ``<topic_prefix>/<name>``
  (default prefix ``algorithm``), and columns of the ROS-free results;
- ``parameters``: name -> default (float, int, bool or str); instances take overrides as
  keyword arguments, live as ROS parameters (``-p threshold:=2.5``); ``self.params`` holds them;
- ``setup(period, nominal)``: called once before the first step with the control period [s] and
  the actuator's nominal (design) parameters; ``reset()`` restarts the internal state;
- ``step(t, u)``: ``t`` the tick's time [s] (tick index times the period), ``u`` the inputs by
  name; returns every output by name;
- ``health()``: ``None`` or :class:`Health` (level OK/WARN/ERROR, a message, key/values),
  published live as ``diagnostic_msgs/DiagnosticArray`` and scored in sweeps (ERROR = detection);
- ``steps(t, u)`` (optional): a whole run's ticks in one call, for the hosts that hold one
  (:meth:`Algorithm.steps`).

A bad class path, a missing input or output name, or an algorithm that raises is one
:class:`~servovalve_twin.errors.TwinError` line naming the algorithm and the step time.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from typing import Any, Mapping

import numpy as np

from ..errors import TwinError
from ..physics.signals import NAMES

#: the signals an algorithm may read: the twin's Float64 topics (HD adds port pressures)
SIGNALS = NAMES
OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR'}


class AlgorithmError(TwinError):
    """An algorithm could not be loaded, is malformed, or failed during a step."""


@dataclasses.dataclass(frozen=True)
class Health:
    """A health verdict: level (OK 0, WARN 1, ERROR 2, as diagnostic_msgs), message, values."""

    level: int = OK
    message: str = ''
    values: Mapping[str, float] = dataclasses.field(default_factory=dict)


class Algorithm:
    """Base class of a user's algorithm (see the module docstring)."""

    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    parameters: Mapping[str, Any] = {}
    #: live topics are ``<topic_prefix>/<output>``
    topic_prefix: str = 'algorithm'

    def __init__(self, **params: Any):
        unknown = sorted(set(params) - set(self.parameters))
        if unknown:
            raise AlgorithmError(f'algorithm {self.title}: unknown parameter {unknown[0]!r}; '
                                 f'expected one of {sorted(self.parameters)}')
        self.params = {k: _coerce(self.title, k, v, self.parameters[k])
                       for k, v in {**dict(self.parameters), **params}.items()}
        self.period: float | None = None
        self.nominal = None

    @property
    def title(self) -> str:
        return type(self).__name__

    def setup(self, period: float, nominal) -> None:
        """Called once by the host before the first step; the default keeps both and resets."""
        self.period = period
        self.nominal = nominal
        self.reset()

    def reset(self) -> None:
        """Restart the internal state (a new run)."""

    def step(self, t: float, u: Mapping[str, float]) -> Mapping[str, float]:
        raise NotImplementedError

    def health(self) -> Health | None:
        return None

    def steps(self, t: np.ndarray, u: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, str]]] | None:
        """Optional: many ticks in one call, exactly as :meth:`step` and :meth:`health` would
        give them one at a time; hosts holding a whole run (``evaluate``, sweeps) use it, live
        hosts call :meth:`step`. ``t``: the ticks' times [s]; ``u``: one row per tick, one
        column per input in ``inputs`` order. Returns the outputs (one row per tick, columns
        in ``outputs`` order), the health level per tick, and ``(tick, message)`` at each
        change of level to WARN or ERROR; or None (the default: step one tick at a time)."""
        return None


def _coerce(title: str, name: str, value: Any, default: Any) -> Any:
    kind = type(default)
    try:
        if kind is bool:
            if isinstance(value, str):
                if value.lower() in ('true', '1', 'yes', 'on'):
                    return True
                if value.lower() in ('false', '0', 'no', 'off'):
                    return False
                raise ValueError(value)
            return bool(value)
        if kind is int and not isinstance(value, bool):
            if float(value) != int(float(value)):
                raise ValueError(value)
            return int(float(value))
        if kind is float:
            # (nan passes every comparison as False: a threshold of nan never trips)
            if not math.isfinite(float(value)):
                raise ValueError(value)
            return float(value)
        return kind(value) if default is not None else value
    except (TypeError, ValueError, OverflowError):
        raise AlgorithmError(f'algorithm {title}: parameter {name} must be a finite '
                             f'{kind.__name__}, got {value!r}') from None


def load_algorithm(spec: Any, params: Mapping[str, Any] | None = None) -> Algorithm:
    """An instance from ``'package.module:ClassName'``, a class or an instance (``params``
    apply to the first two)."""
    if isinstance(spec, Algorithm):
        if params:
            raise AlgorithmError(f'algorithm {spec.title}: parameters go to the class, not to '
                                 'an instance')
        return spec
    cls = spec
    if isinstance(spec, str):
        mod_name, sep, cls_name = spec.partition(':')
        if not sep or not mod_name or not cls_name:
            raise AlgorithmError(f'algorithm class path must be package.module:ClassName, got '
                                 f'{spec!r}')
        try:
            module = importlib.import_module(mod_name)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 -- the user's module; a
            # sys.exit() at import would otherwise end the host with rc 0 and no output
            raise AlgorithmError(f'algorithm {spec}: cannot import {mod_name!r} '
                                 f'({type(exc).__name__}: {exc})') from None
        cls = getattr(module, cls_name, None)
        if cls is None:
            raise AlgorithmError(f'algorithm {spec}: module {mod_name!r} has no {cls_name!r}')
    if not (isinstance(cls, type) and issubclass(cls, Algorithm)):
        raise AlgorithmError(f'algorithm {spec!r} is not a servovalve_twin.prognostics.'
                             'Algorithm subclass')
    try:
        alg = cls(**dict(params or {}))
    except TwinError:
        raise
    except (Exception, SystemExit) as exc:  # noqa: BLE001 -- the user's constructor
        raise AlgorithmError(f'algorithm {getattr(cls, "__name__", spec)} failed in __init__: '
                             f'{type(exc).__name__}: {exc}') from None
    check_declaration(alg)
    return alg


def check_declaration(alg: Algorithm) -> None:
    bad = [s for s in alg.inputs if s not in SIGNALS]
    if bad:
        raise AlgorithmError(f'algorithm {alg.title}: unknown input {bad[0]!r}; the twin '
                             f'publishes {list(SIGNALS)}')
    if not alg.outputs and type(alg).health is Algorithm.health:
        raise AlgorithmError(f'algorithm {alg.title} declares no outputs and no health')
    for name in alg.outputs:
        if not name or not all(c.isalnum() or c == '_' for c in name):
            raise AlgorithmError(f'algorithm {alg.title}: output name {name!r} is not a valid '
                                 'topic name (letters, digits, underscores)')


class AlgorithmRunner:
    """The one code path every host uses: one tick in, the outputs and health out, every
    failure one line naming the algorithm and the step time."""

    def __init__(self, alg: Algorithm, period: float, nominal):
        check_declaration(alg)
        self.alg = alg
        self.period = period
        #: steps taken, and whether one is under way (a :class:`Watchdog` reads them)
        self.beats = 0
        self.in_step = False
        self._last = OK                      # the level of the last tick :meth:`block` ran
        try:
            alg.setup(period, nominal)
        except TwinError:
            raise
        except (Exception, SystemExit) as exc:  # noqa: BLE001 -- the user's code
            raise AlgorithmError(f'algorithm {alg.title} failed in setup: '
                                 f'{type(exc).__name__}: {exc}') from None

    def step(self, t_ns: int, u: Mapping[str, float]) -> tuple[dict[str, float], Health | None]:
        t = t_ns * 1e-9
        alg = self.alg
        self.beats += 1
        self.in_step = True
        try:
            out = alg.step(t, u)
            health = alg.health()
        except TwinError as exc:
            raise AlgorithmError(f'algorithm {alg.title} at t = {t:.3f} s: {exc}') from None
        except (Exception, SystemExit) as exc:  # noqa: BLE001 -- the user's code
            raise AlgorithmError(f'algorithm {alg.title} raised at t = {t:.3f} s: '
                                 f'{type(exc).__name__}: {exc}') from None
        finally:
            self.in_step = False
        try:
            raw = [out[name] for name in alg.outputs]
        except (KeyError, TypeError) as exc:
            raise self._bad_outputs(t, exc) from None
        # every value a float (the common case, checked at C speed), else each a number
        if set(map(type, raw)) - _FLOAT:
            bad = next((v for v in raw if isinstance(v, bool) or not isinstance(
                v, (int, float, np.floating, np.integer))), None)
            try:
                if bad is not None:
                    raise TypeError(f'{bad!r} is not a number')
                raw = [float(v) for v in raw]
            except (TypeError, ValueError, OverflowError) as exc:
                raise self._bad_outputs(t, exc) from None
        if health is not None:
            _check_health(alg, t, health)
        return dict(zip(alg.outputs, raw)), health

    def steps(self, t_ns: np.ndarray, u: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, str]]] | None:
        """The algorithm's :meth:`Algorithm.steps` over ``u``, checked as :meth:`step` checks
        one tick; None if the algorithm steps one tick at a time."""
        alg = self.alg
        self.beats += 1
        t = np.asarray(t_ns, dtype=np.int64) * 1e-9
        span = f'between t = {t[0]:.3f} and {t[-1]:.3f} s' if len(t) else 'on no ticks'
        try:
            block = alg.steps(t, u)
        except TwinError as exc:
            raise AlgorithmError(f'algorithm {alg.title} {span}: {exc}') from None
        except (Exception, SystemExit) as exc:  # noqa: BLE001 -- the user's code
            raise AlgorithmError(f'algorithm {alg.title} raised {span}: '
                                 f'{type(exc).__name__}: {exc}') from None
        if block is None:
            return None
        try:
            out, level, messages = block
            out = np.asarray(out, dtype=float)
            level = np.asarray(level)
            if out.shape != (len(t), len(alg.outputs)) or level.shape != (len(t),):
                raise ValueError(f'outputs of shape {out.shape} and levels of shape '
                                 f'{level.shape} for {len(t)} ticks')
            if not np.isin(level, list(LEVEL_NAMES)).all():
                raise ValueError(f'a health level outside {sorted(LEVEL_NAMES)}')
            messages = [(int(k), m) for k, m in messages]
            if not all(isinstance(m, str) for _, m in messages):
                raise ValueError('a message that is not a string')
        except (TypeError, ValueError) as exc:
            raise AlgorithmError(f'algorithm {alg.title} {span}: steps() must return '
                                 f'(outputs, levels, messages) as documented ({exc})') from None
        return out, level.astype(np.int8), messages

    def block(self, t_ns: np.ndarray, u: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, str]]]:
        """Outputs, health levels and ``(tick, message)`` changes of consecutive ticks, by
        :meth:`steps` or else :meth:`step` tick after tick. Called block after block over a
        run it gives what one call over the whole run gives (the level carried across)."""
        got = self.steps(t_ns, u)
        if got is None:
            got = _step_by_step(self, t_ns, u, self._last)
        if len(got[1]):
            self._last = int(got[1][-1])
        return got

    def _bad_outputs(self, t: float, exc: Exception) -> AlgorithmError:
        alg = self.alg
        return AlgorithmError(f'algorithm {alg.title} at t = {t:.3f} s: step() must return '
                              f'a number for each output {list(alg.outputs)} '
                              f'({type(exc).__name__}: {exc})')


_FLOAT = {float}
_STR = {str}


def _step_by_step(runner: AlgorithmRunner, t_ns: np.ndarray, table: np.ndarray, last: int):
    """:meth:`AlgorithmRunner.step` tick after tick, as :meth:`Algorithm.steps` returns;
    ``last``: the level before the first tick."""
    names = runner.alg.inputs
    out: list[list[float]] = []
    level = np.zeros(len(t_ns), dtype=np.int8)
    changes = []
    for k, (t, row) in enumerate(zip(np.asarray(t_ns, dtype=np.int64).tolist(),
                                     table.tolist())):
        values, health = runner.step(t, dict(zip(names, row)))
        out.append(list(values.values()))
        now = OK if health is None else health.level
        if now != last and now:
            changes.append((k, health.message))
        level[k] = last = now
    return np.array(out, dtype=float).reshape(len(out), len(runner.alg.outputs)), level, changes


def _check_health(alg: Algorithm, t: float, health: Any) -> None:
    """A Health with a level of OK, WARN or ERROR, a string message and string keys: what
    diagnostic_msgs can carry, and what sweeps score."""
    if type(health) is Health and type(health.level) is int and health.level in LEVEL_NAMES \
            and type(health.message) is str and type(health.values) is dict \
            and not set(map(type, health.values)) - _STR:
        return                              # the common case, checked at C speed
    where = f'algorithm {alg.title} at t = {t:.3f} s: health()'
    if not isinstance(health, Health):
        raise AlgorithmError(f'{where} must return a Health or None, got '
                             f'{type(health).__name__}')
    if isinstance(health.level, bool) or health.level not in LEVEL_NAMES:
        raise AlgorithmError(f'{where} level {health.level!r}: expected OK (0), WARN (1) or '
                             'ERROR (2)')
    if not isinstance(health.message, str):
        raise AlgorithmError(f'{where} message must be a string, got '
                             f'{type(health.message).__name__}')
    if not isinstance(health.values, Mapping) or not all(isinstance(k, str)
                                                         for k in health.values):
        raise AlgorithmError(f'{where} values must map string keys to values')


@dataclasses.dataclass
class AlgorithmRun:
    """An algorithm's outputs over a run, ROS-free: one row per tick."""

    title: str
    t: np.ndarray                            # s
    outputs: dict[str, np.ndarray]
    level: np.ndarray                        # health level per tick (0 where None)
    messages: list[str]

    def first(self, level: int = ERROR, after: float = 0.0) -> float | None:
        hit = np.nonzero((self.level >= level) & (self.t >= after - 1e-9))[0]
        return float(self.t[hit[0]]) if hit.size else None


def run_algorithm(alg: Algorithm, t_ns: np.ndarray, inputs: Mapping[str, np.ndarray],
                  period: float, nominal) -> AlgorithmRun:
    """Step ``alg`` over recorded or simulated ticks (``t_ns`` and one array per input)."""
    missing = [s for s in alg.inputs if s not in inputs]
    if missing:
        raise AlgorithmError(f'algorithm {alg.title} reads {missing[0]!r}, which the run does '
                             f'not have (it has {sorted(inputs)})')
    runner = AlgorithmRunner(alg, period, nominal)
    names = alg.inputs
    table = np.empty((len(t_ns), len(names)))
    for j, s in enumerate(names):
        table[:, j] = inputs[s]
    out, level, changes = runner.block(t_ns, table)
    outputs = {name: out[:, j].copy() for j, name in enumerate(alg.outputs)}
    messages = [m for _, m in changes]
    return AlgorithmRun(alg.title, np.asarray(t_ns) * 1e-9, outputs, level, messages)
