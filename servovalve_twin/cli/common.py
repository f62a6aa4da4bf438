"""What the commands share: the :class:`Command` shape, the one-line-error parser, option
types and the options several commands take."""

from __future__ import annotations

import argparse
import contextlib
import os
from typing import Any


class Command:
    """One ``servovalve-twin`` command: its name and one-line help, its options declared beside
    its body -- the shape of ros2bag's verbs (``add_arguments`` + ``main``). A new command is
    one class in a module of this package and one line in :data:`~.COMMANDS`."""

    name = ''
    help = ''

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the command's options."""

    def main(self, args: argparse.Namespace) -> int:
        raise NotImplementedError


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and exit code 2."""

    def error(self, message: str):  # noqa: D401 -- argparse's hook
        self.exit(2, f'{self.prog}: error: {message}\n')


def add_param_options(p: argparse.ArgumentParser) -> None:
    p.add_argument('--param', action='append', metavar='NAME=VALUE', default=[],
                   help='override a parameter of config/eha.yaml (repeatable); '
                        '`servovalve-twin params` lists them')


def add_foxglove_option(p: argparse.ArgumentParser) -> None:
    p.add_argument('--foxglove', type=int, nargs='?', const=8765, default=None, metavar='PORT',
                   help='serve the topics live to the Foxglove app (Foxglove WebSocket on '
                        'ws://127.0.0.1:PORT, default 8765; layout: config/foxglove_layout.json)')


def add_algorithm_options(p: argparse.ArgumentParser, *, required: bool = True) -> None:
    p.add_argument('--algorithm', required=required, metavar='MOD:CLASS',
                   help='the Algorithm, package.module:ClassName')
    p.add_argument('--algorithm-param', action='append', default=[], metavar='NAME=VALUE',
                   help='set a parameter of the algorithm (repeatable)')


def add_scenario_options(p: argparse.ArgumentParser) -> None:
    """A valve model, a scenario and parameter overrides (``simulate``)."""
    from ..physics.valves import VALVE_MODEL_NAMES
    p.add_argument('--valve-model', required=True, metavar='NAME',
                   help='valve model: ' + ', '.join(VALVE_MODEL_NAMES))
    p.add_argument('--scenario', default='paper', metavar='paper|FILE.yaml',
                   help='built-in scenario name or YAML file (default: paper)')
    add_param_options(p)


def miscoverage(text: str) -> float:
    """A conformal level's ``alpha``: a number in (0, 0.5] (0.1: 90 % intervals)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not 0 < v <= 0.5:
        raise argparse.ArgumentTypeError(f'expected alpha in (0, 0.5] (0.1: 90 % intervals), '
                                         f'got {text!r}')
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not v > 0 or v != v or v == float('inf'):
        raise argparse.ArgumentTypeError(f'expected a positive finite number, got {text!r}')
    return v


def nonnegative_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not 0 <= v < float('inf'):
        raise argparse.ArgumentTypeError(f'expected a finite number >= 0, got {text!r}')
    return v


def seed_int(text: str) -> int:
    """A seed: an integer in [0, 2**63 - 1]."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected an integer, got {text!r}') from None
    if not 0 <= v < 2 ** 63:
        raise argparse.ArgumentTypeError(f'expected an integer in [0, 2**63 - 1], got {text}')
    return v


def float_list(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated numbers, got {text!r}'
                                         ) from None
    if not vals or any(v != v or abs(v) == float('inf') for v in vals):
        raise argparse.ArgumentTypeError(f'expected comma-separated finite numbers, got {text!r}')
    return vals


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    """``--param NAME=VALUE`` items, typed by the parameter schema."""
    from ..physics.params import parse_assignments
    return parse_assignments(args.param)


def algorithm_params(args: argparse.Namespace) -> dict[str, str]:
    """``--algorithm-param NAME=VALUE`` (typed by the algorithm from its defaults)."""
    from ..twin.config import parse_assignments_text
    return parse_assignments_text(getattr(args, 'algorithm_param', None) or [],
                                  '--algorithm-param')


@contextlib.contextmanager
def discovery_off(enabled: bool = True):
    """A single-process twin needs no DDS discovery; without it no other graph on the same
    ROS_DOMAIN_ID can cross-talk with the lockstep. rcl reads the variable when a context is
    initialised, so it is set for the run only and restored after."""
    key = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
    saved = os.environ.get(key)
    if enabled:
        os.environ[key] = 'OFF'
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved
