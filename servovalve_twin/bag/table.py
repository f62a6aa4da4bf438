"""The one builder of a run's 1 ms signal table (``simulate``'s CSV columns) from per-tick
series of the twin's Float64 topics: used by the twin on what it recorded and by the reader
on what a bag holds, so both give the same rows.

A row exists for every whole millisecond at which every present signal other than the port
pressures has a value. P1 and P2 exist only while a model with port pressures (HD) is in
force -- after a mid-run switch, for part of the run -- so they never remove a row: they are
NaN where absent, and left out when never present.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import BagError
from ..physics.simulate import CSV_COLUMNS, OUTPUT_PERIOD_NS, PORT_COLUMNS


def signal_table(series: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """``{'t': s, 'com': ..., 'p1': ...}`` from ``{'/com': (log time ns, values), ...}``."""
    cols = {}
    for col in CSV_COLUMNS[1:] + PORT_COLUMNS:
        if f'/{col}' not in series:
            continue
        t, v = (np.asarray(a) for a in series[f'/{col}'])
        on_grid = t % OUTPUT_PERIOD_NS == 0
        cols[col] = (t[on_grid] // OUTPUT_PERIOD_NS, v[on_grid].astype(float))
    if not any(c not in PORT_COLUMNS for c in cols):
        raise BagError('the bag holds none of the twin topics ' + ', '.join(CSV_COLUMNS[1:]))
    common = None
    for col, (ms, _) in cols.items():
        if col not in PORT_COLUMNS:
            common = ms if common is None else np.intersect1d(common, ms)
    out = {'t': common * (OUTPUT_PERIOD_NS * 1e-9)}
    for col, (ms, v) in cols.items():
        if col in PORT_COLUMNS:
            full = np.full(common.shape, np.nan)
            idx = np.searchsorted(ms, common)
            hit = (idx < ms.size) & (ms[np.minimum(idx, ms.size - 1)] == common)
            full[hit] = v[idx[hit]]
            out[col] = full
        else:
            out[col] = v[np.searchsorted(ms, common)]
    return out
