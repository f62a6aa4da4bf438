"""The console scripts' entry points. Importing a node pulls in rclpy and numba -- seconds on a
busy machine -- so each entry point imports its module here, where Ctrl-C during the import is
one line and exit code 130 instead of a traceback."""

from __future__ import annotations

import importlib
import sys


def _run(module: str, func: str = 'main') -> int:
    try:
        target = getattr(importlib.import_module(module), func)
    except KeyboardInterrupt:
        print('interrupted while starting', file=sys.stderr)
        return 130
    return target()


def cli() -> int:
    return _run('servovalve_twin.cli')


def command_generator() -> int:
    return _run('servovalve_twin.nodes.sources', 'main_command_generator')


def load_supply() -> int:
    return _run('servovalve_twin.nodes.sources', 'main_load_supply')


def ecu() -> int:
    return _run('servovalve_twin.nodes.ecu')


def plant() -> int:
    return _run('servovalve_twin.nodes.plant')


def clock() -> int:
    return _run('servovalve_twin.nodes.clock')


def monitor() -> int:
    return _run('servovalve_twin.nodes.monitor')


def algorithm() -> int:
    return _run('servovalve_twin.nodes.algorithm')


def player() -> int:
    return _run('servovalve_twin.nodes.player')


def twin() -> int:
    return _run('servovalve_twin.twin.executable')


def replay() -> int:
    return _run('servovalve_twin.apps.replay')
