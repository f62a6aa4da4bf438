"""The ``twin`` executable (``ros2 run servovalve_twin twin``): the whole graph in one process,
configured with ``--ros-args -p``: the options of ``servovalve-twin run`` under their
parameter names (one table, :class:`~.config.TwinConfig`), and the physical parameters."""

from __future__ import annotations

import sys
from typing import Sequence

from ..nodes.process import ros_main
from ..nodes.rosargs import ros_parameters
from ..physics.params import PARAM_NAMES
from .config import TwinConfig
from .lockstep import run_twin

USAGE = ('usage: twin --ros-args [-p NAME:=VALUE ...] [-r __ns:=/NS] [--params-file FILE]\n'
         '  NAME: ' + ', '.join(TwinConfig.names()) + ', or a physical parameter '
         '(servovalve-twin params lists them)\n'
         'example: ros2 run servovalve_twin twin --ros-args -p valve_model:=HD '
         '-p scenario:=paper -p bag:=bags/hd')


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin twin --ros-args -p valve_model:=C4 -p scenario:=paper
    [-p bag:=bags/my_run | -p record:=false] [-p monitor:=SQ] [-p estimator:=SQ]
    [-p algorithm:="['pkg.mod:Class']"] [-p clock:=follow | -p followers:=1]
    [-p real_time_factor:=1.0] [-r __ns:=/left]``; other ``-p NAME:=VALUE`` set physical
    parameters. Recording is on by default, into ``bags/<scenario>_<valve_model>_<UTC
    time>``."""
    def body(context, stopped) -> int:
        values = ros_parameters(context, 'twin', TwinConfig.names(),
                                allow=lambda n: n in PARAM_NAMES)
        config = TwinConfig.from_values({k: v for k, v in values.items()
                                         if k not in PARAM_NAMES})
        physical = {k: v for k, v in values.items() if k in PARAM_NAMES}

        def on_tick(k: int, twin) -> None:
            if k == 0:
                # one line once the first tick has run: a supervisor (and bench_sigint)
                # knows it is up
                print(f'twin: running {config.valve_model} on {twin.scenario.name}'
                      + (f' in {twin.namespace}' if twin.namespace else ''), flush=True)
                if stopped():                 # asked before the twin took the signals over
                    twin.request_stop()
        result = run_twin(config, physical, on_tick=on_tick, context=context,
                          keep_values=False)
        state = 'interrupted' if result.interrupted else 'done'
        print(f'twin: {state}: {result.simulated_s:.3f} s simulated with {config.valve_model} '
              f'in {result.wall_s:.2f} s (real-time factor '
              f'{result.simulated_s / max(result.wall_s, 1e-9):.1f})'
              + (f'; bag {result.bag}' if result.bag else ''))
        for line in result.verdicts:
            print(f'twin: {line}')
        # a stop by SIGINT/SIGTERM is a clean end for a ROS executable (its bag is complete
        # up to there): 0, so that launch does not report the process as died
        return 0
    return ros_main('twin', body, args, USAGE)


if __name__ == '__main__':
    sys.exit(main())
