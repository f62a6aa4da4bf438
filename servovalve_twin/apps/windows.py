"""A run's rows and windows, for comparing it (:mod:`.compare`) or reporting on it: a bag read
block by block or a ``simulate`` table held whole, and its windows -- the recorded scenario's
phases (split at every breakpoint) and named windows, or, without a scenario, phases split where
the inputs step.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..physics.signals import INPUTS


def run_blocks(path: str | Path):
    """A run's 1 ms rows as ``(source, rows)`` blocks: a bag's read block by block
    (:func:`~..bag.reader.iter_signal_blocks`), a ``simulate`` table's whole (a file of the
    user's own, held as it is)."""
    if is_table(path):
        from ..runs import read_table
        return iter([(None, read_table(Path(path), require=('t', 'xj')))])
    from ..bag.reader import iter_signal_blocks
    return iter_signal_blocks(path)


def run_windows(path: str | Path) -> dict[str, tuple[float, float]]:
    """:func:`load_run`'s windows of a bag (:func:`bag_windows`, its signals not held) or a
    table."""
    if is_table(path):
        from ..runs import read_table
        return _phases_from_inputs(read_table(Path(path), require=('t', 'xj')))
    return bag_windows(path)


def run_span_ms(path: str | Path) -> int:
    """The span of a run's rows [ms]: a bag's from its summary (its messages unread)."""
    if is_table(path):
        from ..runs import read_table
        t = read_table(Path(path), require=('t', 'xj'))['t']
        return int(round((t[-1] - t[0]) * 1000)) if t.size else 0
    from ..bag.anybag import open_any_bag
    bag = open_any_bag(path, require_metadata=True)
    return bag.duration_ns // 1_000_000


def load_run(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, tuple[float, float]]]:
    """A run's 1 ms signals from a bag (directory or .mcap) or a ``simulate`` CSV, and its
    windows: the scenario's phases (split at every breakpoint) and named windows."""
    from ..bag.reader import read_bag
    from ..runs import read_table
    p = Path(path)
    if p.suffix in ('.csv', '.parquet'):
        signals = read_table(p, require=('t', 'xj'))
        return signals, _phases_from_inputs(signals)
    run = read_bag(p)
    raw = run.scenario()
    windows = _phases_from_inputs(run.signals) if raw is None else _scenario_windows(raw)
    return run.signals, windows


def _scenario_windows(raw: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """The windows of a recorded scenario: its phases (split at every breakpoint) and its
    named windows."""
    from ..physics.scenario import scenario_from_dict
    scn = scenario_from_dict(raw)
    # a phase that is one of the named windows is that window (the paper's phase1..phase6
    # repeated run1..drop row for row)
    named = {tuple(span) for span in scn.windows.values()}
    phases = [span for span in scn.phases() if tuple(span) not in named]
    return {**{f'phase{i + 1}': span for i, span in enumerate(phases)}, **scn.windows}


#: more phases than this (smoothly varying inputs): no phase windows
MAX_PHASES = 20


def is_table(path: str | Path) -> bool:
    """A ``simulate`` CSV or Parquet table, not a bag."""
    return Path(path).suffix in ('.csv', '.parquet')


def bag_windows(path: str | Path) -> dict[str, tuple[float, float]]:
    """:func:`load_run`'s windows of a bag without holding its signals: from its provenance's
    scenario, else from its inputs read block by block."""
    from ..bag.anybag import open_any_bag
    from ..bag.reader import iter_signal_blocks
    raw = open_any_bag(path, require_metadata=True).provenance.scenario
    if raw is not None:
        return _scenario_windows(raw)
    cuts: set[float] = set()
    prev: dict[str, float] = {}
    t_first = t_last = None
    for _, rows in iter_signal_blocks(path):
        t = rows['t']
        t_first = float(t[0]) if t_first is None else t_first
        t_last = float(t[-1])
        if len(cuts) <= MAX_PHASES + 1:         # more phases than that: none (_phases)
            _input_steps(rows, prev, cuts)
    return _phases(cuts | {t_first, t_last})


def _input_steps(rows: Mapping[str, np.ndarray], prev: dict[str, float], cuts: set) -> None:
    """Add to ``cuts`` the times at which Com, FR or PSR step within ``rows`` or from
    ``prev`` (each one's last value before them, updated)."""
    t = np.asarray(rows['t'])
    for sig in INPUTS:
        if sig in rows and len(rows[sig]):
            v = np.asarray(rows[sig])
            if sig in prev and v[0] != prev[sig]:
                cuts.add(float(t[0]))
            cuts.update(float(x) for x in t[1:][v[1:] != v[:-1]])
            prev[sig] = v[-1]


def _phases(cuts: set, max_phases: int = MAX_PHASES) -> dict[str, tuple[float, float]]:
    if len(cuts) - 1 > max_phases:
        return {}
    cuts_sorted = sorted(cuts)
    return {f'phase{i + 1}': (a, b) for i, (a, b) in enumerate(zip(cuts_sorted, cuts_sorted[1:]))}


def _phases_from_inputs(signals: Mapping[str, np.ndarray], max_phases: int = MAX_PHASES
                        ) -> dict[str, tuple[float, float]]:
    """Phases split where Com, FR or PSR step (none for smoothly varying inputs)."""
    t = np.asarray(signals['t'])
    cuts = {float(t[0]), float(t[-1])}
    _input_steps(signals, {}, cuts)
    return _phases(cuts, max_phases)
