"""``evaluate``: run an :class:`~servovalve_twin.prognostics.algorithm.Algorithm` on a recorded
bag, ROS-free -- the ticks the twin's lockstep fed it live, in the same order, with the same
floats, so the outputs equal the live ones to the bit (tested). Any rosbag2 bag that holds the
algorithm's inputs as std_msgs/Float64 topics works (:mod:`..bag.anybag`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..bag.anybag import open_any_bag
from ..bag.cdr import decode_float64
from ..bag.reader import read_provenance
from ..errors import BagError
from ..physics.params import EhaParams
from ..prognostics.algorithm import AlgorithmRun, load_algorithm, run_algorithm
from .replay import recorded_params

FLOAT64 = 'std_msgs/msg/Float64'


def bag_inputs(bag_path: str | Path, names) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The ticks (log times, ns) at which every one of ``names`` was recorded, and each
    signal's value at them."""
    bag = open_any_bag(bag_path)
    series = {}
    for name in names:
        topic = f'/{name}'
        info = bag.topics.get(topic)
        if info is None:
            raise BagError(f'bag {str(bag_path)!r} has no {topic} topic (the algorithm reads '
                           f'{list(names)}; the bag has {sorted(bag.topics)})')
        if info.type != FLOAT64:
            raise BagError(f'bag {str(bag_path)!r}: {topic} is {info.type}, not {FLOAT64}')
        t, v = [], []
        for _, log_ns, data in bag.messages(topics=[topic]):
            t.append(log_ns)
            v.append(decode_float64(data))
        series[name] = (np.array(t, dtype=np.int64), np.array(v))
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


def bag_nominal(bag_path: str | Path) -> tuple[EhaParams, float]:
    """The nominal parameters and control period the bag was recorded with (the twin's
    provenance record), or the defaults and 1 ms for a bag without one (not the twin's, or
    sqlite3)."""
    p = Path(bag_path)
    files = [p] if p.is_file() else sorted(p.glob('*.mcap'))
    prov = read_provenance(files[0]) if files and files[0].suffix == '.mcap' else {}
    return recorded_params(prov, p), float(prov.get('control_period', 1e-3))


def evaluate(bag_path: str | Path, algorithm: Any, params: Mapping[str, Any] | None = None
             ) -> AlgorithmRun:
    alg = load_algorithm(algorithm, params)
    t_ns, inputs = bag_inputs(bag_path, alg.inputs)
    nominal, period = bag_nominal(bag_path)
    return run_algorithm(alg, t_ns, inputs, period, nominal)


def run_to_json(run: AlgorithmRun, bag: str | Path) -> dict[str, Any]:
    from ..prognostics.algorithm import ERROR, WARN
    return dict(algorithm=run.title, bag=str(bag), ticks=int(len(run.t)),
                first_warn=run.first(WARN), first_error=run.first(ERROR),
                max_level=int(run.level.max()) if len(run.level) else 0,
                messages=run.messages, t=run.t.tolist(),
                outputs={k: v.tolist() for k, v in run.outputs.items()},
                level=run.level.tolist())
