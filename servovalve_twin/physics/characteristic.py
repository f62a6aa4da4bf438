"""The paper's Fig. 3: zero-to-full-stroke pressure characteristic P12(XS) at fixed QJ."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import ModelError
from .params import EhaParams
from .valve_state import V_FAIL, V_P1, V_P2
from .valves import get_valve_model


#: a test bench's resolution is far coarser: the bounds keep a typo (1e9 points) from
#: exhausting memory
MAX_POINTS = 100_001
MAX_CURVES = 100


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
    if not 2 <= n_points <= MAX_POINTS:
        raise ModelError(f'the number of XS points must be in [2, {MAX_POINTS}], got {n_points}')
    if not 1 <= len(qj) <= MAX_CURVES:
        raise ModelError(f'the number of QJ curves must be in [1, {MAX_CURVES}], got {len(qj)}')
    bad = [q for q in [psr, *qj] if not math.isfinite(q)]
    if bad:
        raise ModelError(f'PSR and QJ must be finite numbers, got {bad[0]!r}')
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
                # no steady state found here (an iterative model's solver failed): a blank
                # point, counted, and the sweep goes on from rest
                vs = model.initial_state(p)
            cols['xs'].append(float(xs))
            cols['qj'].append(float(q))
            cols['p12'].append(np.nan if failed else float(p12))
            if model.has_ports:
                cols['p1'].append(np.nan if failed else float(vs[V_P1]))
                cols['p2'].append(np.nan if failed else float(vs[V_P2]))
    return {k: np.array(v) for k, v in cols.items()}
