"""Figures: time overlays of runs (the paper's Figs. 19-23) and pressure characteristics
(Fig. 3). Matplotlib with the Agg backend, imported only when a figure is drawn."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..outputs import output_path
from .compare import COMPARED


def plot_overlay(runs: Mapping[str, Mapping[str, np.ndarray]], path: str | Path, *,
                 title: str = '', reference: str | None = None,
                 signals: Sequence[str] = ('xj', 'dxj', 'p12', 'xs'),
                 shade: Sequence[tuple[float, float]] = (),
                 windows: Mapping[str, tuple[float, float]] | None = None,
                 inputs: bool = False) -> None:
    """Stacked time plots of several runs, in the manner of the paper's Figs. 19-23: one axis
    per signal (XJ, DXJ, P12, XS against t); the reference drawn black and dashed.

    ``inputs`` adds the command Com on the XJ axis and a first axis with the load FR and the
    supply PSR (what the runs were asked to do); ``windows`` (name -> (t0, t1)) are shaded in
    turn and named in a legend, ``shade`` are plain grey spans."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    first = next(iter(runs.values()))
    show_inputs = inputs and 'fr' in first and 'psr' in first
    n = len(signals) + (1 if show_inputs else 0)
    fig, axes = plt.subplots(n, 1, figsize=(8.0, 2.1 * n), sharex=True)
    axes = list(np.atleast_1d(axes))
    if show_inputs:
        ax = axes.pop(0)
        ax.plot(first['t'], np.asarray(first['fr']) * 1e-3, color='C3', lw=1.0, label='FR [kN]')
        ax.set_ylabel('FR [kN]', color='C3')
        ax2 = ax.twinx()
        ax2.plot(first['t'], np.asarray(first['psr']) * 1e-6, color='C2', lw=1.0,
                 label='PSR [MPa]')
        ax2.set_ylabel('PSR [MPa]', color='C2')
        ax.set_title(title or 'inputs')
        ax.grid(True, lw=0.3)
        title = ''
        _shade(ax, shade, windows, legend=True)
    for ax, sig in zip(axes, signals):
        label, unit, scale = COMPARED.get(sig, (sig.upper(), 'SI', 1.0))
        for name, data in runs.items():
            if sig not in data:
                continue
            style = dict(color='k', ls='--', lw=1.2) if name == reference else dict(lw=1.0)
            ax.plot(data['t'], np.asarray(data[sig]) * scale, label=name, **style)
        if show_inputs and sig == 'xj' and 'com' in first:
            ax.plot(first['t'], np.asarray(first['com']) * scale, color='0.5', lw=0.8, ls=':',
                    label='Com')
        _shade(ax, shade, windows, legend=False)
        ax.set_ylabel(f'{label} [{unit}]')
        ax.grid(True, lw=0.3)
    lines = [h for h in axes[0].get_lines() if not h.get_label().startswith('_')]
    axes[0].legend(handles=lines, loc='best', fontsize=8, ncol=min(4, len(runs) + 1))
    axes[-1].set_xlabel('t [s]')
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    with output_path(path) as tmp:              # whole or absent
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def _shade(ax, shade, windows, legend: bool) -> None:
    for t0, t1 in shade:
        ax.axvspan(t0, t1, color='0.9', zorder=0)
    for i, (name, (t0, t1)) in enumerate((windows or {}).items()):
        ax.axvspan(t0, t1, color=f'C{i % 10}', alpha=0.12 if legend else 0.06, zorder=0,
                   label=name)
    if legend and windows:
        ax.legend(loc='upper left', fontsize=7, ncol=min(6, len(windows)), title='windows',
                  title_fontsize=7)


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
    with output_path(path) as tmp:              # whole or absent
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
