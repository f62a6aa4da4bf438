"""``evaluate``: run an :class:`~servovalve_twin.prognostics.algorithm.Algorithm` on a recorded
bag, ROS-free -- the ticks the twin's lockstep fed it live, in the same order, with the same
floats, so the outputs equal the live ones to the bit (tested). Any rosbag2 bag that holds the
algorithm's inputs as std_msgs/Float64 topics works (:mod:`..bag.anybag`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..bag.anybag import AnyBag, open_any_bag
from ..bag.reader import FLOAT64, float64_series
from ..errors import BagError
from ..physics.params import EhaParams
from ..prognostics.algorithm import AlgorithmRun, load_algorithm, run_algorithm


def bag_inputs(bag: AnyBag, names) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The ticks (log times, ns) at which every one of ``names`` was recorded, and each
    signal's value at them."""
    bag_path = bag.path
    topics = {name: bag.provenance.topic(name) for name in names}     # '/left/xj' namespaced
    for name in names:
        topic = topics[name]
        info = bag.topics.get(topic)
        if info is None:
            raise BagError(f'bag {str(bag_path)!r} has no {topic} topic (the algorithm reads '
                           f'{list(names)}; the bag has {sorted(bag.topics)})')
        if info.type != FLOAT64:
            raise BagError(f'bag {str(bag_path)!r}: {topic} is {info.type}, not {FLOAT64}')
    got = float64_series(bag, list(topics.values()))
    series = {name: got.get(topics[name], (np.zeros(0, dtype=np.int64), np.zeros(0)))
              for name in names}
    common = None
    for t, _ in series.values():
        common = t if common is None else np.intersect1d(common, t)
    if common is None or common.size == 0:
        raise BagError(f'bag {str(bag_path)!r}: the inputs {list(names)} share no tick')
    out = {}
    for name, (t, v) in series.items():
        _, idx = np.unique(t, return_index=True)         # one value per tick: the first
        tt, vv = t[idx], v[idx]
        out[name] = vv[np.searchsorted(tt, common)]
    return common, out


def bag_nominal(bag: AnyBag) -> tuple[EhaParams, float]:
    """The nominal parameters and control period the bag was recorded with (the twin's
    provenance record), or the defaults and 1 ms for a bag without one."""
    prov = bag.provenance
    return prov.eha_params(bag.path), prov.control_period or 1e-3


def evaluate(bag_path: str | Path, algorithm: Any, params: Mapping[str, Any] | None = None
             ) -> AlgorithmRun:
    alg = load_algorithm(algorithm, params)
    bag = open_any_bag(bag_path)
    t_ns, inputs = bag_inputs(bag, alg.inputs)
    nominal, period = bag_nominal(bag)
    return run_algorithm(alg, t_ns, inputs, period, nominal)


def run_to_json(run: AlgorithmRun, bag: str | Path) -> dict[str, Any]:
    from ..prognostics.algorithm import ERROR, WARN
    return dict(algorithm=run.title, bag=str(bag), ticks=int(len(run.t)),
                first_warn=run.first(WARN), first_error=run.first(ERROR),
                max_level=int(run.level.max()) if len(run.level) else 0,
                messages=run.messages, t=run.t.tolist(),
                outputs={k: v.tolist() for k, v in run.outputs.items()},
                level=run.level.tolist())
