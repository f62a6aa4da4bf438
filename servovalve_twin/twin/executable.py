"""The ``twin`` executable (``ros2 run servovalve_twin twin``): the whole graph in one process,
configured with ``--ros-args -p``."""

from __future__ import annotations

import sys
from typing import Sequence

import rclpy

from ..config import default_bag_dir, load_scenario
from ..errors import TwinError
from ..nodes.rosargs import init_context, ros_parameters, stray_arguments
from ..physics.params import PARAM_NAMES
from .lockstep import run_twin

USAGE = ('usage: twin --ros-args -p valve_model:=NAME -p scenario:=NAME|FILE '
         '-p control_period:=S [-p bag:=DIR | -p record:=false] [-p overwrite:=true] '
         '[-p monitor:=C2] [-p foxglove:=8765] [-p clock:=own|follow] '
         '[-p followers:=N] [-p real_time_factor:=X] [-p clock_period:=S] [-r __ns:=/NS] '
         '[-p PARAM:=VALUE ...]')
OPTIONS = ('valve_model', 'scenario', 'control_period', 'bag', 'record', 'overwrite',
           'monitor', 'foxglove', 'clock', 'followers', 'real_time_factor', 'clock_period')


def _seconds(values: dict, name: str, default: float | None) -> float | None:
    """``values.pop(name)`` as a positive number (an integer given for it too)."""
    v = values.pop(name, default)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < float('inf'):
        raise TwinError(f'parameter {name} = {v!r}: expected a positive number')
    return float(v)


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin twin --ros-args -p valve_model:=C4 -p scenario:=paper
    -p control_period:=0.001 [-p bag:=bags/my_run] [-p record:=false] [-p overwrite:=true]
    [-p monitor:=C2] [-p clock:=follow | -p followers:=1] [-p real_time_factor:=1.0]
    [-p clock_period:=0.01]
    [-r __ns:=/left]``; other ``-p NAME:=VALUE`` set physical parameters. Recording is on by
    default, into ``bags/<scenario>_<valve_model>_<UTC time>``."""
    argv = list(sys.argv if args is None else args)
    if stray_arguments(argv):
        print(USAGE, file=sys.stderr)
        return 2
    context, argv = init_context(argv)
    try:
        values = ros_parameters(context, 'twin', OPTIONS, allow=lambda n: n in PARAM_NAMES)
        valve_model = values.pop('valve_model', 'C2')
        scenario = values.pop('scenario', 'paper')
        period = _seconds(values, 'control_period', 1e-3)
        bag = values.pop('bag', '')
        record = bool(values.pop('record', True))
        overwrite = bool(values.pop('overwrite', False))
        monitor = values.pop('monitor', '') or None
        foxglove = values.pop('foxglove', None)
        clock = values.pop('clock', 'own')
        followers = values.pop('followers', 0)
        if isinstance(followers, bool) or not isinstance(followers, int):
            raise TwinError(f'parameter followers = {followers!r}: expected an integer >= 0')
        rtf = _seconds(values, 'real_time_factor', None)
        clock_period = _seconds(values, 'clock_period', 1e-2)
        if record and not bag:
            bag = default_bag_dir(load_scenario(scenario).name, valve_model)
        # one line once the first tick has run: a supervisor (and bench_sigint) knows it is up
        started = lambda k, twin: k == 0 and print(   # noqa: E731
            f'twin: running {valve_model} on {twin.scenario.name}'
            + (f' in {twin.namespace}' if twin.namespace else ''), flush=True)
        result = run_twin(valve_model, scenario, values, control_period=period, on_tick=started,
                          bag=bag if record else None, context=context, keep_values=False,
                          monitor=monitor, overwrite=overwrite,
                          foxglove=None if foxglove is None else int(foxglove),
                          clock=str(clock), clock_period=clock_period, followers=followers,
                          real_time_factor=rtf)
    except TwinError as exc:
        print(f'twin: error: {exc}', file=sys.stderr)
        return 2
    finally:
        rclpy.try_shutdown(context=context)
    state = 'interrupted' if result.interrupted else 'done'
    print(f'twin: {state}: {result.simulated_s:.3f} s simulated with {valve_model} in '
          f'{result.wall_s:.2f} s (real-time factor '
          f'{result.simulated_s / max(result.wall_s, 1e-9):.1f})'
          + (f'; bag {result.bag}' if result.bag else ''))
    # a stop by SIGINT/SIGTERM is a clean end for a ROS executable (its bag is complete up to
    # there): 0, so that launch does not report the process as died
    return 0


if __name__ == '__main__':
    sys.exit(main())
