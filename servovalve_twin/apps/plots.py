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
    per signal (XJ, DXJ, P12, XS against t). The reference is drawn wide, grey and under the
    runs, which are thin and coloured on top: a run equal to its reference stays visible.

    ``inputs`` adds the command Com on the XJ axis and an axis each for the load FR and the
    supply PSR (what the runs were asked to do: on one axis with two scales, FR's line hid
    under PSR's); ``windows`` (name -> (t0, t1)) are drawn as labelled bars on a strip above
    the signals, their edges as faint lines across them (nine shaded, overlapping windows hid
    the traces); ``shade`` are plain grey spans. The legend sits outside the traces."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    first = next(iter(runs.values()))
    show_inputs = inputs and 'fr' in first and 'psr' in first
    rows = _window_rows(windows or {})
    heights = ([0.28 * max(1, len(rows))] if rows else []) + \
        ([1.1, 1.1] if show_inputs else []) + [2.0] * len(signals)
    fig, axes = plt.subplots(len(heights), 1, figsize=(10.0, sum(heights) + 0.9), sharex=True,
                             gridspec_kw=dict(height_ratios=heights))
    axes = list(np.atleast_1d(axes))
    if rows:
        _window_strip(axes.pop(0), rows)
    edges = sorted({t for t0, t1 in (windows or {}).values() for t in (t0, t1)})
    if show_inputs:
        for sig, scale, unit, color in (('fr', 1e-3, 'kN', 'C3'), ('psr', 1e-6, 'MPa', 'C2')):
            ax = axes.pop(0)
            ax.plot(first['t'], np.asarray(first[sig]) * scale, color=color, lw=1.0)
            ax.set_ylabel(f'{sig.upper()} [{unit}]')
            ax.grid(True, lw=0.3)
            _marks(ax, shade, edges)
    for ax, sig in zip(axes, signals):
        label, unit, scale = COMPARED.get(sig, (sig.upper(), 'SI', 1.0))
        for name, data in runs.items():
            if sig not in data:
                continue
            style = (dict(color='0.55', lw=3.0, alpha=0.6, zorder=2) if name == reference
                     else dict(lw=1.0, zorder=3))
            ax.plot(data['t'], np.asarray(data[sig]) * scale, label=name, **style)
        if show_inputs and sig == 'xj' and 'com' in first:
            ax.plot(first['t'], np.asarray(first['com']) * scale, color='k', lw=0.8, ls=':',
                    label='Com', zorder=4)
        _marks(ax, shade, edges)
        ax.set_ylabel(f'{label} [{"µm" if unit == "um" else unit}]')
        ax.grid(True, lw=0.3)
    # the runs' legend outside the traces, right of the first signal's axis
    ax0 = axes[0]
    ax0.legend(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    axes[-1].set_xlabel('t [s]')
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with output_path(path) as tmp:              # whole or absent
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def _window_rows(windows: Mapping[str, tuple[float, float]]) -> list[list[tuple]]:
    """The windows on rows so that none overlaps another on its row (first fit, in order)."""
    rows: list[list[tuple]] = []
    for name, (t0, t1) in windows.items():
        for row in rows:
            if all(t1 <= a or t0 >= b for _, a, b in row):
                row.append((name, t0, t1))
                break
        else:
            rows.append([(name, t0, t1)])
    return rows


def _window_strip(ax, rows) -> None:
    """The named windows as thin labelled bars, one row per layer of overlap."""
    for k, row in enumerate(rows):
        y = len(rows) - 1 - k
        for name, t0, t1 in row:
            ax.barh(y, t1 - t0, left=t0, height=0.7, color='0.88', edgecolor='0.5', lw=0.5)
            ax.text(0.5 * (t0 + t1), y, name, ha='center', va='center', fontsize=7)
    ax.set_ylim(-0.5, len(rows) - 0.5)
    ax.set_yticks([])
    ax.set_ylabel('windows', fontsize=8)
    for side in ('top', 'right', 'left'):
        ax.spines[side].set_visible(False)


def _marks(ax, shade, edges) -> None:
    for t0, t1 in shade:
        ax.axvspan(t0, t1, color='0.9', zorder=0)
    for t in edges:
        ax.axvline(t, color='0.8', lw=0.6, zorder=1)


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
    ax.set_xlabel('XS [µm]')
    ax.set_ylabel('P12 [MPa]')
    ax.set_title(f'Pressure characteristic at PSR = {psr * 1e-6:g} MPa (paper Fig. 3)')
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with output_path(path) as tmp:              # whole or absent
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
