"""Replay: drive the ECU and plant with a bag's Com, FR and PSR on simulated time, record the
new run and compare it with the bag.

A bag the twin recorded carries the scenario it ran (its provenance record): when the recorded
inputs are that scenario's values at every tick (checked block by block), the scenario is
replayed as it is -- an hour of a sine command is a few numbers. Otherwise (another tool's
bag, an input changed mid-run) the recorded inputs become a step scenario with a breakpoint
wherever a recorded value changes, so the schedule nodes publish exactly the recorded values
at every tick -- at most :data:`MAX_BREAKPOINTS` of them per input. Parameters, control period
and (unless overridden) the valve model come from the bag's provenance record.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..bag.anybag import AnyBag, open_any_bag
from ..bag.reader import iter_float64_blocks
from ..config import default_bag_dir
from ..errors import BagError, TwinError
from ..physics.params import EhaParams
from ..physics.scenario import Scenario, scenario_from_dict
# the inputs a replay drives the twin with, in the order Scenario.inputs gives them
from ..physics.signals import INPUTS


#: the most breakpoints a replayed input may have (~100 bytes each in the scenario, and the
#: scenario is recorded in the new bag's provenance): a 1 kHz input that changes at every
#: tick reaches it after 200 s
MAX_BREAKPOINTS = 200_000


def replay_scenario(bag: AnyBag) -> Scenario:
    """What a replay of ``bag`` runs: the twin's recorded scenario when the recorded inputs
    are its values at every tick (and they end together), else :func:`scenario_from_bag`."""
    raw = bag.provenance.scenario
    if raw is not None:
        scn = bag.provenance.scenario_object(bag.path)
        end = _recorded_end_if(bag, scn)
        if end is not None:
            duration = end * 1e-9
            # a run stopped early: its breakpoints after the stop are not part of it
            out = {k: [p for p in raw[k] if p[0] <= duration] if isinstance(raw[k], list)
                   else raw[k] for k in INPUTS if k in raw}
            out.update(name=f'replay of {bag.path.name}', duration=duration)
            if raw.get('faults'):
                out['faults'] = [f for f in raw['faults'] if float(f['at']) <= duration]
            try:
                return scenario_from_dict(out)
            except TwinError:           # e.g. a ramp cut short by the stop: the values, then
                pass
    return scenario_from_bag(bag)


def _recorded_end_if(bag: AnyBag, scn: Scenario) -> int | None:
    """The last tick [ns] of the recorded inputs if every recorded value of Com, FR and PSR is
    ``scn``'s at its time (from t = 0, all three to the same end); else None."""
    topics = {sig: bag.provenance.topic(sig) for sig in INPUTS}
    if any(t not in bag.topics for t in topics.values()):
        return None
    ends = {}
    for series in iter_float64_blocks(bag, list(topics.values())):
        for i, (sig, topic) in enumerate(topics.items()):
            t, v = series.get(topic, ((), ()))
            if not len(t):
                continue
            if sig not in ends and t[0] != 0:
                return None
            want = scn.inputs(np.asarray(t, dtype=np.int64))[i]
            if not np.array_equal(v, want, equal_nan=True):
                return None
            ends[sig] = int(t[-1])
    if len(ends) != len(INPUTS) or len(set(ends.values())) != 1:
        return None
    return next(iter(ends.values()))


def scenario_from_bag(bag: AnyBag) -> Scenario:
    """The recorded Com, FR, PSR as a step scenario (breakpoints where a value changes), with
    the recorded run's scheduled faults; read block by block (memory that grows with the
    number of changes, not with the bag)."""
    topics = {sig: bag.provenance.topic(sig) for sig in INPUTS}
    for sig, topic in topics.items():
        if topic not in bag.topics:
            raise BagError(f'bag {str(bag.path)!r} has no /{sig} topic to replay')
    raw: dict[str, Any] = {sig: [] for sig in INPUTS}
    last: dict[str, float] = {}
    end: dict[str, int] = {}
    for series in iter_float64_blocks(bag, list(topics.values())):
        for sig, topic in topics.items():
            t, v = series.get(topic, ((), ()))
            if not len(t):
                continue
            if sig not in end and t[0] != 0:
                raise BagError(f'bag {str(bag.path)!r}: /{sig} does not start at t = 0')
            # a breakpoint where the value changes (the first value, and NaN, always)
            keep = np.concatenate([[sig not in last or not v[0] == last[sig]],
                                   v[1:] != v[:-1]])
            raw[sig] += [[float(ti) * 1e-9, float(vi)] for ti, vi in zip(t[keep], v[keep])]
            if len(raw[sig]) > MAX_BREAKPOINTS:
                raise BagError(f'bag {str(bag.path)!r}: /{sig} changes at more than '
                               f'{MAX_BREAKPOINTS} ticks; a replay drives the twin through a '
                               'step scenario of its recorded values, allowed at most '
                               f'{MAX_BREAKPOINTS} steps per input (a bag the twin recorded '
                               'replays its scenario instead)')
            last[sig], end[sig] = float(v[-1]), int(t[-1])
    for sig in INPUTS:
        if sig not in end:
            raise BagError(f'bag {str(bag.path)!r}: /{sig} does not start at t = 0')
    raw['duration'] = min(end.values()) * 1e-9
    raw['name'] = f'replay of {bag.path.name}'
    recorded = bag.provenance.scenario or {}
    if recorded.get('faults'):
        # the recorded run's injected faults are part of what it was: replay them too
        raw['faults'] = [f for f in recorded['faults'] if float(f['at']) <= raw['duration']]
    for sig in INPUTS:
        raw[sig] = [p for p in raw[sig] if p[0] <= raw['duration']]
    return scenario_from_dict(raw)


def bag_params(run) -> EhaParams:
    """The parameters the bag (an :class:`AnyBag` or a :class:`BagRun`) was recorded with
    (defaults for a bag without provenance)."""
    return run.provenance.eha_params(run.path)


def replay(bag: str | Path, *, valve_model: str | None = None, out: str | Path | None = None,
           overrides: Mapping[str, Any] | None = None, overwrite: bool = False,
           **twin_kwargs) -> tuple[AnyBag, Any, dict]:
    """Replay ``bag``; returns (the original, opened; the new :class:`~..twin.TwinResult`;
    metrics of the new run against the original). Both bags are read block by block.
    ``twin_kwargs``: :func:`~..twin.run_twin`'s (``context``, ``handle_signals``, ...)."""
    from ..twin import run_twin
    from ..twin.config import TwinConfig
    from .compare import compare_bags
    original = open_any_bag(bag, require_metadata=True)
    scenario = replay_scenario(original)
    prov = original.provenance
    model = valve_model or prov.valve_model or 'C2'
    period = prov.control_period or 1e-3
    src = Path(bag)
    out = Path(out) if out is not None else default_bag_dir(f'{src.name}_replay', model)
    # keep_values off: the comparison reads the new bag (the run's table would grow with it)
    twin_kwargs.setdefault('keep_values', False)
    config = TwinConfig(valve_model=model, scenario=scenario, control_period=period, bag=out,
                        overwrite=overwrite)
    result = run_twin(config, overrides, base_params=bag_params(original), **twin_kwargs)
    # the recorded scenario's named windows, as a run of it reports them
    named = (prov.scenario or {}).get('windows') or {}
    metrics = compare_bags(bag, out, {k: tuple(v) for k, v in named.items()})
    return original, result, metrics


def main(args: Sequence[str] | None = None) -> int:
    """``ros2 run servovalve_twin replay --ros-args -p bag:=bags/paper_HD [-p valve_model:=C2]
    [-p out:=DIR]``."""
    from ..nodes.process import ros_main
    from ..nodes.rosargs import ros_parameters
    from .compare import format_table

    def body(context, stopped) -> int:
        values = ros_parameters(context, 'replay', ('bag', 'valve_model', 'out'))
        if not values.get('bag'):
            raise TwinError('give the bag to replay: --ros-args -p bag:=DIR')
        # (a stop asked before the twin took the signals over: its first tick sees it)
        _, result, metrics = replay(
            values['bag'], valve_model=values.get('valve_model') or None,
            out=values.get('out') or None, context=context,
            on_tick=lambda k, twin: twin.request_stop() if k == 0 and stopped() else None)
        print(f'replayed into {result.bag}')
        print(format_table(metrics))
        return 130 if result.interrupted else 0
    return ros_main('replay', body, args, 'usage: replay --ros-args -p bag:=DIR '
                    '[-p valve_model:=NAME] [-p out:=DIR]')
