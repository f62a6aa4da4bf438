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
    next...). HD adds the port pressures P1, P2. The sweep warm-starts each point from the
    previous one, as a slow quasi-static test-bench sweep would.

    The compressible HD option describes dynamics, not a static curve: the characteristic is
    always the pseudo-static one.
    """
    model = get_valve_model(valve_model)
    if n_points < 2:
        raise ModelError(f'n_points must be >= 2, got {n_points}')
    p = params.replace(compressible=False)
    P = p.kernel()
    xs_grid = np.linspace(-p.XSM, p.XSM, n_points)
    cols: dict[str, list[float]] = {'xs': [], 'qj': [], 'p12': []}
    if model.has_ports:
        cols.update(p1=[], p2=[])
    for q in qj:
        vs = model.initial_state(p)
        for xs in xs_grid:
            p12 = model.fn(float(xs), float(q), float(psr), P, vs)
            if vs[V_FAIL]:
                raise ModelError(f'{model.name} failed to converge at XS={xs:g} m, QJ={q:g}')
            cols['xs'].append(float(xs))
            cols['qj'].append(float(q))
            cols['p12'].append(float(p12))
            if model.has_ports:
                cols['p1'].append(float(vs[V_P1]))
                cols['p2'].append(float(vs[V_P2]))
    return {k: np.array(v) for k, v in cols.items()}


def plot_characteristic(curves: dict[str, dict[str, np.ndarray]], path, psr: float) -> None:
    """One line per (model, QJ): P12 [MPa] against XS [um], the layout of the paper's Fig. 3."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for name, c in curves.items():
        for q in np.unique(c['qj']):
            m = c['qj'] == q
            ls = '--' if name == 'HD' else '-'
            ax.plot(c['xs'][m] * 1e6, c['p12'][m] * 1e-6, ls=ls, lw=1.0,
                    label=f'{name} QJ={q * 6e4:.3g} l/min')
    ax.axhline(psr * 1e-6, color='0.5', lw=0.5)
    ax.axhline(-psr * 1e-6, color='0.5', lw=0.5)
    # a valve forced to pass flow near null reaches many times PSR (HD does): keep the
    # interesting range in view
    ax.set_ylim(-1.5 * psr * 1e-6, 1.5 * psr * 1e-6)
    ax.set_xlabel('XS [um]')
    ax.set_ylabel('P12 [MPa]')
    ax.set_title(f'Pressure characteristic at PSR = {psr * 1e-6:g} MPa (paper Fig. 3)')
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
