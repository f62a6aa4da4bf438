"""Figures: time overlays of runs (the paper's Figs. 19-23) and pressure characteristics
(Fig. 3). Matplotlib with the Agg backend, imported only when a figure is drawn."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .compare import COMPARED


def plot_overlay(runs: Mapping[str, Mapping[str, np.ndarray]], path: str | Path, *,
                 title: str = '', reference: str | None = None,
                 signals: Sequence[str] = ('xj', 'dxj', 'p12', 'xs'),
                 shade: Sequence[tuple[float, float]] = ()) -> None:
    """Stacked time plots of several runs, in the manner of the paper's Figs. 19-23: one axis
    per signal (XJ, DXJ, P12, XS against t); the reference drawn black and dashed."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(signals), 1, figsize=(8.0, 2.1 * len(signals)), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, sig in zip(axes, signals):
        label, unit, scale = COMPARED.get(sig, (sig.upper(), 'SI', 1.0))
        for name, data in runs.items():
            if sig not in data:
                continue
            style = dict(color='k', ls='--', lw=1.2) if name == reference else dict(lw=1.0)
            ax.plot(data['t'], np.asarray(data[sig]) * scale, label=name, **style)
        for t0, t1 in shade:
            ax.axvspan(t0, t1, color='0.9', zorder=0)
        ax.set_ylabel(f'{label} [{unit}]')
        ax.grid(True, lw=0.3)
    axes[0].legend(loc='best', fontsize=8, ncol=min(4, len(runs)))
    axes[-1].set_xlabel('t [s]')
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


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
