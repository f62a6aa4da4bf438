"""One configuration of a twin run (and what it gives back, :class:`TwinResult`), filled alike
by ``servovalve-twin run`` (its options) and by the ``twin`` executable (its ``--ros-args -p``
parameters): :class:`TwinConfig`.

Each option is declared once, below, with its help text and its type: the command line derives
its ``--options`` from the fields, the executable the parameter names it accepts (the physical
parameters besides: ``--param M=400`` there, ``-p M:=400.0`` here), so the two accept the same
options by construction.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.params import EhaParams
from ..physics.scenario import Scenario

#: the twin publishes /clock itself, or follows another owner's
CLOCK_MODES = ('own', 'follow')


def _positive(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
            math.isfinite(v) and v > 0):
        raise TwinError(f'{name} = {v!r}: expected a positive number')
    return float(v)


def _bounded(lo: float, hi: float, what: str) -> Callable[[str, Any], float]:
    """A positive number within [lo, hi]: a period or factor the twin turns into integer
    nanoseconds or a wall-clock wait (1e308 s overflowed; a factor of 1e-300 ran for ever)."""
    def check(name: str, v: Any) -> float:
        v = _positive(name, v)
        if not lo <= v <= hi:
            raise TwinError(f'{name} = {v!r}: expected {what} in [{lo:g}, {hi:g}]')
        return v
    return check


#: the most twins a clock owner may wait for
MAX_FOLLOWERS = 1000


def _count(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_FOLLOWERS:
        raise TwinError(f'{name} = {v!r}: expected a count in [0, {MAX_FOLLOWERS}]')
    return v


def _seed(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 2 ** 63:
        raise TwinError(f'{name} = {v!r}: expected an integer in [0, 2**63 - 1]')
    return v


def _text(name: str, v: Any) -> str:
    if not isinstance(v, str):
        raise TwinError(f'{name} = {v!r}: expected a string')
    return v


def _texts(name: str, v: Any) -> tuple[str, ...]:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) for x in v):
        raise TwinError(f'{name} = {v!r}: expected a list of strings')
    return tuple(x for x in v if x)


def _flag(name: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise TwinError(f'{name} = {v!r}: expected true or false')
    return v


def _port(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 65536:
        raise TwinError(f'{name} = {v!r}: expected a TCP port, 0-65535 (0: any free one)')
    return v


def _clock(name: str, v: Any) -> str:
    if v not in CLOCK_MODES:
        raise TwinError(f'{name} = {v!r}: expected one of {", ".join(CLOCK_MODES)}')
    return v


def option(default: Any, help: str, check: Callable[[str, Any], Any], *,
           metavar: str | None = None, cli: dict | None = None) -> Any:
    """A field of :class:`TwinConfig`: its default, its help, how a value is checked and
    converted, and how the command line spells it (``cli``: argparse keywords)."""
    return dataclasses.field(default=default, metadata=dict(
        help=help, check=check, metavar=metavar, cli=cli or {}))


@dataclasses.dataclass
class TwinConfig:
    """What a twin run is made of (the physical parameters aside: ``overrides``): the
    ``run`` command's options and the ``twin`` executable's ROS parameters, each checked, and
    what :class:`~.lockstep.Twin` takes. From Python, ``scenario`` may also be a
    :class:`~..physics.scenario.Scenario` or a mapping, ``bag`` a path, and ``algorithm``
    hold classes, instances and (class, parameters) pairs.

    What some fields do in the twin (:class:`~.lockstep.Twin`): ``clock_period`` --
    ``/clock`` is published every this much simulated time (the lockstep does not need it:
    every message is tied to its tick, and at 1 ms each ``/clock`` message costs a delivery to
    every node's time source, bench/README.md); ``namespace`` -- the actuator's nodes, topics
    and the bag's topic names move under it (``/left/xj``), ``/clock`` stays global;
    ``clock`` -- 'own' publishes ``/clock``, 'follow' runs each tick only once another
    owner's ``/clock`` has reached it (a follower's results do not depend on the owner's
    pace); ``real_time_factor`` -- paced to this many simulated seconds per wall second,
    checked at every ``clock_period``, every ``/clock`` then on DDS so that a
    ``use_sim_time`` node beside it sees each of its timer periods; ``followers`` -- the clock
    owner starts once this many following twins are on the graph (discovery takes 0.4-1.2 s
    here; a late follower misses no tick); ``sensor_seed`` -- the noise realisation of the
    scenario's sensors; ``foxglove`` -- every message served live on this localhost port (0:
    any free one; :mod:`..nodes.live`).
    """

    valve_model: str = option('C2', 'valve model: a name of the registry '
                              '(servovalve-twin --help lists them)', _text, metavar='NAME')
    scenario: str | Scenario | Mapping = option(
        'paper', "built-in scenario name or YAML file (default paper); its 'faults:' section "
        'injects faults ([{at: 0.3, fault: leakage_growth, severity: 10}]; servovalve-twin '
        'faults lists them)', _text, metavar='paper|FILE.yaml')
    control_period: float = option(1e-3, 'lockstep period [s] (default 0.001; must divide '
                                   '1 ms)', _positive, metavar='S')
    clock_period: float = option(1e-2, '/clock publication period in simulated time [s] '
                                 '(default 0.01)', _bounded(1e-6, 1e3, 'seconds'),
                                 metavar='S', cli=dict(type=float))
    real_time_factor: float | None = option(
        None, 'pace simulated time to X simulated seconds per wall second (1: real time), '
        'so that ordinary use_sim_time nodes beside the twin keep up; default: as fast as '
        'possible', _bounded(1e-3, 1e6, 'a factor'), metavar='X', cli=dict(type=float))
    namespace: str = option('', "the actuator's namespace: its nodes and topics under /NS "
                            '(/NS/xj), so that several actuators share one graph; /clock '
                            'stays global', _text, metavar='NS')
    clock: str = option('own', "own: publish /clock (the graph's one clock owner, default); "
                        "follow: run each tick once another owner's /clock reaches it", _clock,
                        cli=dict(choices=CLOCK_MODES))
    followers: int = option(0, 'the clock owner starts once N twins following its /clock '
                            '(other namespaces) are on the graph (default 0: at once)', _count,
                            metavar='N')
    sensor_seed: int | None = option(
        None, "the noise realisation of the scenario's sensors (default their seed; the bag "
        'records the one used)', _seed, metavar='N', cli=dict(type=int))
    bag: str | Path = option('', 'bag directory (default bags/<scenario>_<model>_<UTC time>)',
                             _text, metavar='DIR')
    record: bool = option(True, 'record a bag (default true)', _flag,
                          cli=dict(flag='--no-bag', action='store_false',
                                   help='do not record'))
    overwrite: bool = option(False, 'replace an existing bag', _flag,
                             cli=dict(action='store_true'))
    monitor: str = option('', 'run the monitor node beside the plant with this simplified '
                          'model', _text, metavar='MODEL')
    estimator: str = option('', 'run the estimator node: diagnosis with this simplified model '
                            'over the last 0.5 s, every 0.25 s (estimator/<fault>_severity, '
                            'diagnostics)', _text, metavar='MODEL')
    algorithm: tuple[Any, ...] = option(
        (), 'host this Algorithm in the lockstep (repeatable); its outputs are published and '
        'recorded', _texts, metavar='MOD:CLASS', cli=dict(action='append'))
    algorithm_param: tuple[str, ...] = option(
        (), 'set a parameter of the algorithms (repeatable)', _texts, metavar='NAME=VALUE',
        cli=dict(action='append'))
    foxglove: int | None = option(
        None, 'serve the topics live to the Foxglove app (Foxglove WebSocket on '
        'ws://127.0.0.1:PORT, default 8765; layout: config/foxglove_layout.json)', _port,
        metavar='PORT', cli=dict(type=int, nargs='?', const=8765))

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The option names (the executable's ``-p`` names)."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> 'TwinConfig':
        """From typed values (ROS parameters, or the command line's parsed options): each one
        checked; an unknown name is refused with the list of known ones."""
        fields = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(fields))
        if unknown:
            raise TwinError(f'unknown option {unknown[0]!r}; expected one of {list(fields)}')
        kw = {}
        for name, value in values.items():
            if value is None:
                continue                           # left to its default
            kw[name] = fields[name].metadata['check'](name, value)
        return cls(**kw)

    @classmethod
    def add_arguments(cls, parser, *, required: Sequence[str] = ('valve_model',)) -> None:
        """The command line's options, one per field (``--valve-model``, ...)."""
        for f in dataclasses.fields(cls):
            cli = dict(f.metadata['cli'])
            flag = cli.pop('flag', '--' + f.name.replace('_', '-'))
            kw = dict(help=cli.pop('help', f.metadata['help']), dest=f.name, **cli)
            if kw.get('action') in ('store_true', 'store_false'):
                kw['default'] = f.default
            else:
                kw.setdefault('metavar', f.metadata['metavar'])
                kw['default'] = None                # unset: the field's default
                if 'type' not in kw and f.metadata['check'] is _positive:
                    kw['type'] = float
                elif 'type' not in kw and f.metadata['check'] is _count:
                    kw['type'] = int
            if f.name in required:
                kw['required'] = True
            if f.name == 'valve_model':
                from ..physics.valves import VALVE_MODEL_NAMES
                kw['help'] = 'valve model: ' + ', '.join(VALVE_MODEL_NAMES)
            parser.add_argument(flag, **kw)

    @classmethod
    def from_args(cls, args) -> 'TwinConfig':
        return cls.from_values({n: getattr(args, n) for n in cls.names()})

    def algorithm_params(self) -> dict[str, str]:
        """``algorithm_param`` as {name: text} (typed by each algorithm from its defaults)."""
        return parse_assignments_text(self.algorithm_param, 'algorithm_param')

    def algorithms(self) -> list[tuple[Any, dict | None]]:
        """The hosted algorithms as (class path or class, parameters) or instances: the
        user's (``algorithm``: class paths, which take ``algorithm_param``; from Python also
        classes, instances, or (class, parameters) pairs), then the estimator's."""
        params = self.algorithm_params()
        out: list[Any] = [a if isinstance(a, tuple) or not isinstance(a, (str, type))
                          else (a, params) for a in self.algorithm]
        if self.estimator:
            out.append(('servovalve_twin.prognostics.estimator:Estimator',
                        {'model': self.estimator,
                         'model_form': self.estimator != self.valve_model}))
        return out

    def bag_dir(self, scenario_name: str) -> str | None:
        """Where it records: ``bag``, or bags/<scenario_name>_<model>_<UTC time> (the name of
        the scenario as loaded); None without a recording."""
        if not self.record:
            return None
        if self.bag:
            return str(self.bag)
        from ..config import default_bag_dir
        return str(default_bag_dir(scenario_name, self.valve_model))

    @property
    def shares_the_graph(self) -> bool:
        """A namespaced, following, waiting or paced twin is there to share a graph with other
        processes (DDS discovery on)."""
        return bool(self.namespace or self.clock == 'follow' or self.followers
                    or self.real_time_factor is not None)


def parse_assignments_text(items: Sequence[str], what: str) -> dict[str, str]:
    """``NAME=VALUE`` items as {name: value text}; a malformed one is one error line."""
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        if not sep or not name.strip():
            raise TwinError(f'{what} expects NAME=VALUE, got {item!r}')
        out[name.strip()] = value.strip()
    return out


@dataclasses.dataclass
class TwinResult:
    valve_model: str
    scenario: Scenario
    params: EhaParams
    control_period: float
    ticks: int
    wall_s: float
    simulated_s: float
    interrupted: bool = False
    bag: Path | None = None
    signals: dict[str, np.ndarray] | None = None
    messages: int = 0
    verdicts: list[str] = dataclasses.field(default_factory=list)   # monitor and algorithms


def check_clock_options(clock: str, real_time_factor: float | None, followers: int) -> None:
    if clock not in CLOCK_MODES:
        raise TwinError(f'clock {clock!r}: expected one of {", ".join(CLOCK_MODES)}')
    if real_time_factor is not None and not (
            math.isfinite(real_time_factor) and real_time_factor > 0):
        raise TwinError(f'real-time factor {real_time_factor}: expected a positive number '
                        '(1.0 is real time)')
    if real_time_factor is not None and clock == 'follow':
        raise TwinError('a twin that follows /clock is paced by the clock owner: give the '
                        'real-time factor to the owner')
    if followers and clock == 'follow':
        raise TwinError('followers: only the clock owner waits for its followers')
    if followers < 0:
        raise TwinError(f'followers {followers}: expected a count >= 0')


def scenario_label(spec: Any, scenario: Scenario) -> str:
    """What the schedule nodes' ``scenario`` parameter says: the name or file the twin was
    given, or the scenario's own name when it was given as data."""
    if isinstance(spec, (str, Path)):
        return str(spec)
    return scenario.name


def ros_param(name: str, params: EhaParams):
    """A node's ROS parameter for ``params``' value; a derived parameter left to its
    derivation is 0.0, as the nodes declare it (so a fault on CLk still re-derives C4_alpha)."""
    value = getattr(params, name)
    return ros_param_value(name, 0.0 if value is None else value)


def ros_param_value(name: str, value: Any):
    """An rclpy Parameter of ``value``'s type (rclpy imported here: the command line reads
    this module to build its options without it)."""
    from rclpy.parameter import Parameter
    if isinstance(value, bool):
        return Parameter(name, Parameter.Type.BOOL, value)
    if isinstance(value, int):
        return Parameter(name, Parameter.Type.INTEGER, value)
    return Parameter(name, Parameter.Type.DOUBLE, float(value))


__all__ = ['TwinConfig', 'TwinResult', 'CLOCK_MODES', 'parse_assignments_text',
           'check_clock_options', 'ros_param', 'ros_param_value', 'scenario_label']
