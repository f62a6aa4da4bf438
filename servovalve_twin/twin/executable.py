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
         '[-p monitor:=C2] [-p foxglove:=8765] [-p PARAM:=VALUE ...]')
OPTIONS = ('valve_model', 'scenario', 'control_period', 'bag', 'record', 'overwrite',
           'monitor', 'foxglove')


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin twin --ros-args -p valve_model:=C4 -p scenario:=paper
    -p control_period:=0.001 [-p bag:=bags/my_run] [-p record:=false] [-p overwrite:=true]
    [-p monitor:=C2]``; other ``-p NAME:=VALUE`` set physical parameters. Recording is on by
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
        period = float(values.pop('control_period', 1e-3))
        bag = values.pop('bag', '')
        record = bool(values.pop('record', True))
        overwrite = bool(values.pop('overwrite', False))
        monitor = values.pop('monitor', '') or None
        foxglove = values.pop('foxglove', None)
        if record and not bag:
            bag = default_bag_dir(load_scenario(scenario).name, valve_model)
        result = run_twin(valve_model, scenario, values, control_period=period,
                          bag=bag if record else None, context=context, keep_values=False,
                          monitor=monitor, overwrite=overwrite,
                          foxglove=None if foxglove is None else int(foxglove))
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
    return 130 if result.interrupted else 0


if __name__ == '__main__':
    sys.exit(main())
