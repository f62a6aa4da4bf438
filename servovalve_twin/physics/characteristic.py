"""The paper's Fig. 3: zero-to-full-stroke pressure characteristic P12(XS) at fixed QJ."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ModelError
from .params import EhaParams
from .valve_state import V_FAIL, V_P1, V_P2
from .valves import get_valve_model


def characteristic(valve_model: str, params: EhaParams, psr: float, qj: Sequence[float],
                   n_points: int = 401) -> dict[str, np.ndarray]:
    """P12 against XS over [-XSM, XSM] for each QJ (rows: every XS for the first QJ, then the
    next...). HD adds the port pressures P1, P2. A point without a steady state is NaN (``nan``
    in the CSV, a gap in the plot); ``np.isnan(out['p12']).sum()`` counts them. The sweep
    warm-starts each point from the previous one, as a slow quasi-static test-bench sweep would.

    The compressible HD option describes dynamics, not a static curve: the characteristic is
    always the pseudo-static one.
    """
    model = get_valve_model(valve_model)
    if n_points < 2:
        raise ModelError(f'n_points must be >= 2, got {n_points}')
    p = params.replace(compressible=False)
    P = model.kernel(p)
    xs_grid = np.linspace(-p.XSM, p.XSM, n_points)
    cols: dict[str, list[float]] = {'xs': [], 'qj': [], 'p12': []}
    if model.has_ports:
        cols.update(p1=[], p2=[])
    for q in qj:
        vs = model.initial_state(p)
        for xs in xs_grid:
            p12 = model.fn(float(xs), float(q), float(psr), P, vs)
            failed = bool(vs[V_FAIL])
            if failed:
                # no steady state here (e.g. HD at null with a tiny clearance and a forced
                # flow): a blank point, counted, and the sweep goes on from rest
                vs = model.initial_state(p)
            cols['xs'].append(float(xs))
            cols['qj'].append(float(q))
            cols['p12'].append(np.nan if failed else float(p12))
            if model.has_ports:
                cols['p1'].append(np.nan if failed else float(vs[V_P1]))
                cols['p2'].append(np.nan if failed else float(vs[V_P2]))
    return {k: np.array(v) for k, v in cols.items()}
