"""The monitor's tick, compiled: one function that every host of the built-in monitor runs --
the ROS ``monitor`` node one row at a time, ``evaluate``, ``sweep`` and :func:`.monitor_run`
over a run's rows through the same :class:`~.algorithm.AlgorithmRunner` loop.

Per row (one control period; columns :data:`U_COLUMNS`): a row with an input no actuator can
produce (not finite, or beyond its plausibility bound) is dropped -- counted, its row and column
kept for the message -- and the monitor model advances on the last good inputs with the
outputs held; otherwise the monitor model's ECU closes its loop on the model's own XJ, the
model advances one period with Cor, FR, PSR held (the ROS plant's :func:`~..physics.plant.
run_tick`), and the residuals measured - model at the row's instant feed a moving RMS over the
last ``n`` rows (a ring of squared residuals and their running sum) compared with the WARN
and ERROR thresholds; the level is the worst crossed.

Why compiled and why one: the monitor ran as Python around a compiled plant tick (33 us per
row here) beside a second, array form for sweeps (simulate + numpy, 7 us per row) kept equal
by a test. The compiled tick costs 6 us per row entered once per row (the ROS node) and
5.6 us per row over a whole run (``steps``), of which ~5 us is the SQ model's 100 sub-steps:
one implementation, as fast as the array form was (paper scenario, 1001 rows, this machine).
"""

from __future__ import annotations

import numpy as np

from ..jitcache import jit
from ..physics.ecu import ecu_current
from ..physics.plant import run_tick
from ..physics.servovalve import S_DXJ, S_XJ
from ..physics.signals import INPUTS, MEASURED

#: the columns of a row: the scheduled inputs, then the measured outputs
U_COLUMNS = INPUTS + MEASURED
#: the columns of an output row: residual per measured signal, then its moving RMS
OUT_COLUMNS = tuple(f'residual_{s}' for s in MEASURED) + tuple(f'health_{s}' for s in MEASURED)
_NU = len(U_COLUMNS)
_NM = len(MEASURED)

# the state vector ``w`` (float64): plausibility bounds, thresholds, running sums, counters,
# the last good row, the last outputs, the plant tick's scratch
W_BOUND = 0                        # _NU bounds, in U_COLUMNS order
W_THR = W_BOUND + _NU              # warn, error per measured signal
W_SUM = W_THR + 2 * _NM            # running sum of squared residuals per measured signal
W_COUNT = W_SUM + _NM              # rows in the window so far (<= n)
W_HEAD = W_COUNT + 1               # the ring's oldest slot once full
W_DROPPED = W_HEAD + 1
W_GOOD = W_DROPPED + 1             # 1 once a plausible row was seen
W_LEVEL = W_GOOD + 1               # the level of the last assessed row
W_BAD_ROW = W_LEVEL + 1            # the last dropped row (of the last call) and its column
W_BAD_COL = W_BAD_ROW + 1
W_LAST_U = W_BAD_COL + 1
W_LAST_OUT = W_LAST_U + _NU
W_TICK = W_LAST_OUT + 2 * _NM      # run_tick's P12, QJ, P1, P2
W_SIZE = W_TICK + 4


def new_state(bounds, thresholds) -> np.ndarray:
    """A fresh state vector: ``bounds`` per column of :data:`U_COLUMNS`, ``thresholds`` as
    (warn, error) per measured signal."""
    w = np.zeros(W_SIZE)
    w[W_BOUND:W_BOUND + _NU] = bounds
    w[W_THR:W_THR + 2 * _NM] = np.ravel(thresholds)
    w[W_BAD_ROW] = -1.0
    return w


def reset_window(w: np.ndarray, ring: np.ndarray, thresholds) -> None:
    """New thresholds and an empty window (the model's state and the counters kept)."""
    w[W_THR:W_THR + 2 * _NM] = np.ravel(thresholds)
    w[W_SUM:W_SUM + _NM] = 0.0
    w[W_COUNT] = w[W_HEAD] = 0.0
    ring[:] = 0.0


#: what :func:`monitor_rows` returns when every row was done
DONE = -1


def monitor_rows_for(model_id: int):
    """:func:`monitor_rows` for a monitor model: compiled ahead of time (:mod:`~..aot`) where
    the module of the current sources is built, else the JIT's -- the same arguments."""
    from ..jitcache import aot_loop
    return aot_loop('monitor', model_id) or monitor_rows


@jit
def monitor_rows(model_id, s, vs, P_arr, n_sub, u, w, ring, out, level, stop_on_change):
    """Advance the monitor over the rows of ``u`` (:data:`U_COLUMNS`), writing
    :data:`OUT_COLUMNS` to ``out`` and the health level to ``level``; ``s``, ``vs``: the
    monitor model's plant and valve state, ``w``: the state vector, ``ring``: (measured
    signals, window length) squared residuals.

    Returns :data:`DONE`; ``-2 - i`` if the model failed to converge at row ``i``; or, with
    ``stop_on_change``, the row ``i`` (done) after which the level changed, so that the host
    can take the health message there."""
    n_win = ring.shape[1]
    tick = w[W_TICK:W_TICK + 4]
    for i in range(u.shape[0]):
        good = True
        for c in range(_NU):
            if not abs(u[i, c]) <= w[W_BOUND + c]:      # NaN fails too
                good = False
                w[W_DROPPED] += 1.0
                w[W_BAD_ROW] = i
                w[W_BAD_COL] = c
                break
        if good:
            for c in range(_NU):
                w[W_LAST_U + c] = u[i, c]
            w[W_GOOD] = 1.0
        elif w[W_GOOD] == 0.0:              # nothing good yet: the model stays at rest
            for c in range(2 * _NM):
                out[i, c] = 0.0
            level[i] = 0
            continue
        # the monitor's own loop: its ECU sees its own XJ, as the real ECU sees the plant's
        xj_m = s[S_XJ]
        dxj_m = s[S_DXJ]
        cor = ecu_current(w[W_LAST_U + 0], xj_m, P_arr[0])
        if run_tick(model_id, s, vs, P_arr, cor, w[W_LAST_U + 1], w[W_LAST_U + 2], n_sub,
                    tick) >= 0:
            return -2 - i
        if good:
            model = (xj_m, dxj_m, tick[0])
            slot = int(w[W_HEAD])
            full = w[W_COUNT] >= n_win
            lev = 0
            for m in range(_NM):
                r = u[i, _NU - _NM + m] - model[m]
                v = r * r
                w[W_SUM + m] += v
                if full:
                    w[W_SUM + m] -= ring[m, slot]
                ring[m, slot] = v
                cnt = w[W_COUNT] if full else w[W_COUNT] + 1.0
                ind = np.sqrt(max(w[W_SUM + m], 0.0) / cnt)
                if ind > w[W_THR + 2 * m + 1]:
                    lev = 2
                elif ind > w[W_THR + 2 * m] and lev < 1:
                    lev = 1
                w[W_LAST_OUT + m] = r
                w[W_LAST_OUT + _NM + m] = ind
            if not full:
                w[W_COUNT] += 1.0
            w[W_HEAD] = (slot + 1) % n_win
            changed = lev != w[W_LEVEL]
            w[W_LEVEL] = lev
        else:
            changed = False
        for c in range(2 * _NM):
            out[i, c] = w[W_LAST_OUT + c]
        level[i] = int(w[W_LEVEL])
        if changed and stop_on_change:
            return i
    return DONE
