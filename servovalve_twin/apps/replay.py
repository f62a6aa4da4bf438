"""Replay: drive the ECU and plant with a bag's Com, FR and PSR on simulated time, record the
new run and compare it with the bag.

The recorded inputs become a step scenario with a breakpoint wherever a recorded value changes,
so the schedule nodes publish exactly the recorded values at every tick. Parameters, control
period and (unless overridden) the valve model come from the bag's provenance record.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import BagError, TwinError
from ..physics.params import EhaParams
from ..physics.scenario import Scenario, scenario_from_dict
from ..bag.reader import BagRun, read_bag
from ..config import default_bag_dir


def scenario_from_bag(run: BagRun) -> Scenario:
    """The recorded Com, FR, PSR as a step scenario (breakpoints where a value changes), with
    the recorded run's scheduled faults."""
    raw: dict[str, Any] = {}
    duration_ns = None
    for sig in ('com', 'fr', 'psr'):
        if f'/{sig}' not in run.series:
            raise BagError(f'bag {str(run.path)!r} has no /{sig} topic to replay')
        t, v = run.series[f'/{sig}']
        if t.size == 0 or t[0] != 0:
            raise BagError(f'bag {str(run.path)!r}: /{sig} does not start at t = 0')
        keep = np.concatenate([[True], v[1:] != v[:-1]])
        raw[sig] = [[float(ti) * 1e-9, float(vi)] for ti, vi in zip(t[keep], v[keep])]
        duration_ns = int(t[-1]) if duration_ns is None else min(duration_ns, int(t[-1]))
    raw['duration'] = duration_ns * 1e-9
    raw['name'] = f'replay of {run.path.name}'
    recorded = run.scenario() or {}
    if recorded.get('faults'):
        # the recorded run's injected faults are part of what it was: replay them too
        raw['faults'] = [f for f in recorded['faults'] if float(f['at']) <= raw['duration']]
    for sig in ('com', 'fr', 'psr'):
        raw[sig] = [p for p in raw[sig] if p[0] <= raw['duration']]
    return scenario_from_dict(raw)


def bag_params(run: BagRun) -> EhaParams:
    """The parameters the bag was recorded with (defaults for a bag without provenance)."""
    return run.provenance.eha_params(run.path)


def replay(bag: str | Path, *, valve_model: str | None = None, out: str | Path | None = None,
           overrides: Mapping[str, Any] | None = None, overwrite: bool = False,
           **twin_kwargs) -> tuple[BagRun, Any, dict]:
    """Replay ``bag``; returns (the original, the new :class:`~..twin.TwinResult`, metrics of
    the new run against the original)."""
    from ..twin import run_twin
    from .compare import error_metrics
    original = read_bag(bag)
    scenario = scenario_from_bag(original)
    model = valve_model or original.valve_model or 'C2'
    period = original.control_period or 1e-3
    src = Path(bag)
    out = Path(out) if out is not None else default_bag_dir(f'{src.name}_replay', model)
    result = run_twin(model, scenario, overrides, control_period=period, bag=out,
                      base_params=bag_params(original), overwrite=overwrite, **twin_kwargs)
    new = read_bag(out)
    windows = {}
    sc = original.scenario()
    if sc and sc.get('windows'):
        windows = {k: tuple(v) for k, v in sc['windows'].items()}
    metrics = error_metrics(original.signals, new.signals, windows)
    return original, result, metrics


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin replay --ros-args -p bag:=bags/paper_HD [-p valve_model:=C2]
    [-p out:=DIR]``."""
    import rclpy
    from ..nodes.rosargs import init_context, ros_parameters
    from .compare import format_table
    context, _ = init_context(args)
    try:
        values = ros_parameters(context, 'replay', ('bag', 'valve_model', 'out'))
        if not values.get('bag'):
            raise TwinError('give the bag to replay: --ros-args -p bag:=DIR')
        _, result, metrics = replay(values['bag'], valve_model=values.get('valve_model') or None,
                                    out=values.get('out') or None, context=context)
    except TwinError as exc:
        print(f'replay: error: {exc}', file=sys.stderr)
        return 2
    finally:
        rclpy.try_shutdown(context=context)
    print(f'replayed into {result.bag}')
    print(format_table(metrics))
    return 130 if result.interrupted else 0
