"""Metrics and figures of one run against a reference (normally HD).

Runs are aligned on simulated time in whole milliseconds (the 1 ms output rows of
doc/design/MODELS.md
section 9); errors are ``run - reference``. "RMS error" is the root mean square over the rows
inside a window [t0, t1) -- the last window of a run is closed at the end time.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..errors import TwinError
from ..physics.signals import INPUTS
from .windows import run_blocks

#: signals compared, with their display unit and scale
COMPARED = {'xj': ('XJ', 'mm', 1e3), 'dxj': ('DXJ', 'mm/s', 1e3), 'p12': ('P12', 'MPa', 1e-6),
            'xs': ('XS', 'um', 1e6), 'cor': ('Cor', 'mA', 1e3)}


def align(ref: Mapping[str, np.ndarray], run: Mapping[str, np.ndarray]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row indices of ``ref`` and ``run`` at their common whole-ms times, and those times [s]."""
    ms_ref = np.rint(np.asarray(ref['t']) * 1000).astype(np.int64)
    ms_run = np.rint(np.asarray(run['t']) * 1000).astype(np.int64)
    common, i_ref, i_run = np.intersect1d(ms_ref, ms_run, return_indices=True)
    if common.size < 2:
        raise TwinError('the two runs share fewer than two 1 ms samples: nothing to compare')
    return i_ref, i_run, common * 1e-3


def window_mask(t: np.ndarray, t0: float, t1: float, closed: bool) -> np.ndarray:
    ms = np.rint(t * 1000).astype(np.int64)
    a, b = int(round(t0 * 1000)), int(round(t1 * 1000))
    return (ms >= a) & ((ms <= b) if closed else (ms < b))


def error_metrics(ref: Mapping[str, np.ndarray], run: Mapping[str, np.ndarray],
                  windows: Mapping[str, tuple[float, float]],
                  signals: Iterable[str] = COMPARED) -> dict[str, dict[str, dict[str, float]]]:
    """``{window: {signal: {'rms': .., 'max': .., 'n': ..}}}`` in SI units; the window 'all'
    (the whole common span) is always included."""
    i_ref, i_run, t = align(ref, run)
    t_end = float(t[-1])
    spans = {'all': (float(t[0]), t_end), **dict(windows)}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for wname, (t0, t1) in spans.items():
        mask = window_mask(t, t0, t1, closed=abs(t1 - t_end) < 5e-4)
        row: dict[str, dict[str, float]] = {}
        for sig in signals:
            if sig not in ref or sig not in run:
                continue
            err = np.asarray(run[sig])[i_run][mask] - np.asarray(ref[sig])[i_ref][mask]
            if err.size == 0:
                continue
            row[sig] = dict(rms=float(np.sqrt(np.mean(err ** 2))),
                            max=float(np.max(np.abs(err))), n=int(err.size))
        out[wname] = row
    return out


class _Window:
    """One window's running error sums per signal: rows in [a, b) ms, and the row at b ms
    apart (counted only if b turns out to be the last common row: a closed last window)."""

    def __init__(self, a: int, b: int | None):
        self.a, self.b = a, b
        self.sums: dict[str, list[float]] = {}        # signal -> [sum of squares, max, n]
        self.at_end: dict[str, float] = {}

    def add(self, ms: np.ndarray, sig: str, err: np.ndarray) -> None:
        inside = (ms >= self.a) if self.b is None else (ms >= self.a) & (ms < self.b)
        e = err[inside]
        if e.size:
            acc = self.sums.setdefault(sig, [0.0, 0.0, 0])
            acc[0] += float(np.dot(e, e))
            acc[1] = max(acc[1], float(np.max(np.abs(e))))
            acc[2] += int(e.size)
        if self.b is not None:
            hit = np.flatnonzero(ms == self.b)
            if hit.size:
                self.at_end[sig] = float(err[hit[0]])

    def result(self, end_ms: int) -> dict[str, dict[str, float]]:
        row = {}
        for sig in dict.fromkeys(list(self.sums) + list(self.at_end)):
            ssq, mx, n = self.sums.get(sig, [0.0, 0.0, 0])
            if self.b == end_ms and sig in self.at_end:
                e = self.at_end[sig]
                ssq, mx, n = ssq + e * e, max(mx, abs(e)), n + 1
            if n:
                row[sig] = dict(rms=math.sqrt(ssq / n), max=mx, n=n)
        return row


def _aligned(ref_blocks, run_blocks):
    """Rows of two block streams at their common whole-ms times, block by block: each side's
    rows are held only until the other side has passed them."""
    pend = [None, None]
    streams = [iter(ref_blocks), iter(run_blocks)]
    done = [False, False]

    def take(i):
        for _, rows in streams[i]:
            ms = np.rint(rows['t'] * 1000).astype(np.int64)
            rows = dict(rows, ms=ms)
            pend[i] = rows if pend[i] is None else {
                k: np.concatenate([pend[i][k], v]) for k, v in rows.items()}
            return
        done[i] = True

    while True:
        for i in (0, 1):
            if not done[i] and (pend[i] is None or not pend[i]['ms'].size):
                take(i)
        if any(pend[i] is None or not pend[i]['ms'].size for i in (0, 1)):
            if all(done):
                return
            if any(done[i] and (pend[i] is None or not pend[i]['ms'].size) for i in (0, 1)):
                # one side is over: nothing more is common; read the other to its end (its
                # end-of-bag checks)
                for i in (0, 1):
                    for _ in streams[i]:
                        pass
                return
            continue
        upto = min(pend[0]['ms'][-1], pend[1]['ms'][-1])
        parts = []
        for i in (0, 1):
            k = int(np.searchsorted(pend[i]['ms'], upto, side='right'))
            parts.append({c: v[:k] for c, v in pend[i].items()})
            pend[i] = {c: v[k:] for c, v in pend[i].items()}
        common, ia, ib = np.intersect1d(parts[0]['ms'], parts[1]['ms'], return_indices=True)
        if common.size:
            yield common, {c: v[ia] for c, v in parts[0].items()}, \
                {c: v[ib] for c, v in parts[1].items()}


def compare_bags(ref: str | Path, run: str | Path, windows: Mapping[str, tuple[float, float]],
                 signals: Iterable[str] = COMPARED, plot: 'PlotRows | None' = None
                 ) -> dict[str, dict[str, dict[str, float]]]:
    """:func:`error_metrics` of two runs (bags or tables) driven by the same Com, FR and PSR
    (else refused), read block by block: memory that does not grow with the bags. The sums
    run block by block, so an RMS may differ from the whole-array one in its last bits.
    ``plot``: also gather the rows a figure of the two needs."""
    wins = {name: _Window(int(round(t0 * 1000)), int(round(t1 * 1000)))
            for name, (t0, t1) in windows.items()}
    whole = _Window(0, None)
    last = None
    n = 0
    for ms, a, b in _aligned(run_blocks(ref), run_blocks(run)):
        _same_inputs(a, b, ms * 1e-3)
        last = int(ms[-1])
        n += ms.size
        if plot is not None:
            plot.add(ms, a, b)
        for sig in signals:
            if sig in a and sig in b:
                err = b[sig] - a[sig]
                whole.add(ms, sig, err)
                for w in wins.values():
                    w.add(ms, sig, err)
    if n < 2:
        raise TwinError('the two runs share fewer than two 1 ms samples: nothing to compare')
    out = {'all': whole.result(last)}
    for name, w in wins.items():
        out[name] = w.result(last)
    return out


#: rows a comparison's figure holds at most per run (an 8-inch figure has ~800 pixel columns)
PLOT_ROWS = 20_000


class PlotRows:
    """The rows of two aligned runs a figure needs, in memory bounded by :data:`PLOT_ROWS`:
    every row of a run of at most that many ms; of a longer one, per bin of ``bin_ms`` ms
    each column's minimum and maximum, drawn at the bin's first and last row (a line through
    them covers what the bin's rows cover: peaks stay visible)."""

    def __init__(self, span_ms: int, max_rows: int = PLOT_ROWS):
        self.bin_ms = 1 if span_ms + 1 <= max_rows else -(-(span_ms + 1) // (max_rows // 2))
        self.parts: list[tuple[dict, dict]] = []
        self.tail: dict | None = None                 # the last bin, still open

    def add(self, ms: np.ndarray, a: Mapping[str, np.ndarray], b: Mapping[str, np.ndarray]
            ) -> None:
        cols = [c for c in a if c not in ('t', 'ms') and c in b]
        if self.bin_ms == 1:
            self.parts.append(({c: a[c] for c in ['t'] + cols},
                               {c: b[c] for c in ['t'] + cols}))
            return
        rows = {'ms': ms, **{f'a.{c}': a[c] for c in cols}, **{f'b.{c}': b[c] for c in cols}}
        if self.tail is not None:                     # the open bin continues here?
            rows = {k: np.concatenate([self.tail[k], v]) for k, v in rows.items()
                    if k in self.tail}
        bins = rows['ms'] // self.bin_ms
        cut = int(np.searchsorted(bins, bins[-1]))    # the last bin may go on in the next block
        self.tail = {k: v[cut:] for k, v in rows.items()}
        self._bin({k: v[:cut] for k, v in rows.items()}, bins[:cut], cols)

    def _bin(self, rows, bins, cols) -> None:
        if not bins.size:
            return
        starts = np.flatnonzero(np.concatenate([[True], bins[1:] != bins[:-1]]))
        ends = np.concatenate([starts[1:], [bins.size]]) - 1
        t = np.empty(2 * starts.size)
        t[0::2], t[1::2] = rows['ms'][starts] * 1e-3, rows['ms'][ends] * 1e-3
        out = ({'t': t}, {'t': t})
        for side, key in ((0, 'a'), (1, 'b')):
            for c in cols:
                v = rows[f'{key}.{c}']
                col = np.empty(2 * starts.size)
                col[0::2] = np.fmin.reduceat(v, starts)
                col[1::2] = np.fmax.reduceat(v, starts)
                out[side][c] = col
        self.parts.append(out)

    def runs(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """The two runs' rows to draw."""
        if self.tail is not None and self.tail['ms'].size:
            cols = sorted({k[2:] for k in self.tail if k != 'ms'})
            self._bin(self.tail, self.tail['ms'] // self.bin_ms, cols)
            self.tail = None
        return tuple({c: np.concatenate([p[side][c] for p in self.parts])
                      for c in self.parts[0][side]} for side in (0, 1))


def coverage(metrics: Mapping[str, Any], ref_span_ms: int) -> dict[str, Any]:
    """How much of the reference a comparison covers: the 1 ms rows common to both runs
    (:func:`compare_bags`' whole-run count) against the reference's own rows."""
    common = max((m['n'] for m in metrics.get('all', {}).values()), default=0)
    rows = int(ref_span_ms) + 1
    return dict(common_rows=common, reference_rows=rows, fraction=common / rows)


def coverage_warning(cov: Mapping[str, Any]) -> str | None:
    """One line when the run covers less than the whole reference (a run cut short, a bag
    reindexed after a kill): its errors say nothing of the rest."""
    if cov['common_rows'] >= cov['reference_rows']:
        return None
    return (f'the run covers {cov["common_rows"]} of the reference\'s {cov["reference_rows"]} '
            f'1 ms rows ({cov["fraction"]:.1%}): the errors say nothing of the rest')


def exceeded(metrics: Mapping[str, Any], tolerances: Mapping[str, float]) -> list[str]:
    """Descriptions of every whole-run max error above its tolerance (signal -> SI value)."""
    bad = []
    for sig, tol in tolerances.items():
        m = metrics['all'].get(sig)
        if m is not None and m['max'] > tol:
            bad.append(f'{sig}: max error {m["max"]:.6g} > tolerance {tol:.6g}')
    return bad


def format_table(metrics: Mapping[str, Mapping[str, Mapping[str, float]]],
                 signals: Sequence[str] = tuple(COMPARED)) -> str:
    """A plain-text table: one line per window, RMS/max per signal in display units."""
    sigs = [s for s in signals if any(s in row for row in metrics.values())]
    head = f'{"window":<12}' + ''.join(
        f'{COMPARED[s][0] + " rms/max [" + COMPARED[s][1] + "]":>30}' for s in sigs)
    lines = [head, '-' * len(head)]
    for wname, row in metrics.items():
        cells = []
        for s in sigs:
            m = row.get(s)
            scale = COMPARED[s][2]
            cells.append(f'{m["rms"] * scale:14.4g} / {m["max"] * scale:<11.4g}' if m
                         else f'{"-":>30}')
        lines.append(f'{wname:<12}' + ''.join(f'{c:>30}' for c in cells))
    return '\n'.join(lines)


def provenance_differences(ref: str | Path, run: str | Path) -> list[str]:
    """What differs between two recorded runs besides the valve model -- parameters, scenario,
    control period -- from their provenance records (bags only; nothing for CSVs): a comparison
    of two runs of different actuators or inputs is rarely what was meant."""
    from ..bag.anybag import open_any_bag
    tables = [Path(x).suffix in ('.csv', '.parquet') for x in (ref, run)]
    if all(tables):
        return []
    if any(tables):
        # a table records no ECU period; simulate's default ECU is continuous (the README's
        # tour read SQ at 0.155 mm against a 1 ms bag where the 1 ms twin reads 0.161)
        bag = open_any_bag(run if tables[0] else ref).provenance
        period = bag.control_period if bag else None
        return [f'{ref if tables[0] else run} is a table, which records no ECU period; the '
                f'bag\'s ECU samples every {period * 1e3:g} ms. simulate runs a continuous ECU '
                f'unless given one: compare like with like with simulate --ecu-period {period:g}'
                ] if period else []
    # the provenance records only (the signals were read already)
    a, b = (open_any_bag(x).provenance for x in (ref, run))
    if not a or not b:
        return []
    out = []
    from ..physics.params import DEFAULTS
    # a parameter a bag does not list (recorded before it existed) had its default value
    defaults = DEFAULTS.resolved()
    pa, pb = {**defaults, **a.params}, {**defaults, **b.params}
    changed = sorted(k for k in set(pa) | set(pb) if pa.get(k) != pb.get(k))
    if changed:
        out.append('the runs were made with different parameters: ' + ', '.join(
            f'{k} {pa.get(k)!r} vs {pb.get(k)!r}' for k in changed[:5])
            + (f' (and {len(changed) - 5} more)' if len(changed) > 5 else ''))
    if a.scenario != b.scenario:
        out.append(f'the runs flew different scenarios: {a.scenario_name!r} '
                   f'vs {b.scenario_name!r} (or the same name, changed)')
    if a.control_period != b.control_period:
        out.append(f'the runs had different control periods: {a.control_period} vs '
                   f'{b.control_period} s')
    return out


def _same_inputs(ref: Mapping[str, np.ndarray], run: Mapping[str, np.ndarray], t: np.ndarray
                 ) -> None:
    """Com, FR and PSR of two runs' aligned rows (times ``t`` [s]) agree to 1e-9 relative,
    else one error line at the first row that differs."""
    for sig in INPUTS:
        if sig in ref and sig in run:
            a, b = ref[sig], run[sig]
            bad = np.nonzero(np.abs(a - b) > 1e-9 * np.maximum(1.0, np.abs(a)))[0]
            if bad.size:
                raise TwinError(f'the runs have different inputs: {sig} differs at t = '
                                f'{t[bad[0]]:.3f} s ({a[bad[0]]:g} vs {b[bad[0]]:g})')


def parse_tolerances(items: list[str]) -> dict[str, float]:
    """``SIGNAL=MAX`` items (``compare --tolerance``) as {signal: max error}; ``current`` is
    ``cor``; anything else is one error line naming the signals allowed."""
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        name = name.strip().lower()
        if name == 'current':
            name = 'cor'
        if not sep or name not in COMPARED:
            raise TwinError(f'--tolerance expects SIGNAL=MAX with SIGNAL one of '
                            f'{sorted(COMPARED)}, got {item!r}')
        try:
            out[name] = float(value)
        except ValueError:
            raise TwinError(f'--tolerance {item!r}: {value!r} is not a number') from None
        # (nan never trips, a negative one always does)
        if not 0.0 <= out[name] < math.inf:
            raise TwinError(f'--tolerance {item!r}: the largest error allowed must be a '
                            'finite number >= 0')
    return out
