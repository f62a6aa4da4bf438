"""Layout of a valve model's state vector (a float64 array the compiled physics updates in place).

The simplified models ignore it; C4 keeps its warm start and iteration counts in it; HD its port
pressures, cavitation flags and solver status. Reading it after a call gives the model's
diagnostics without any allocation on the hot path.
"""

import numpy as np

V_P12 = 0       # last P12 [Pa]: C4's warm start
V_P1 = 1        # port-1 absolute pressure [Pa] (HD: warm start / state; NaN otherwise)
V_P2 = 2        # port-2 absolute pressure [Pa]
V_ITER = 3      # iterations of the last call (C4 short run, HD Newton)
V_MAXITER = 4   # largest V_ITER seen since reset
V_NONCONV = 5   # number of calls that hit the iteration cap (C4: reported, not hidden)
V_CAV = 6       # cavitation flags of the last call: 1 = port 1 clamped, 2 = port 2 clamped
V_NCAV = 7      # number of calls with a cavitating port
V_FAIL = 8      # 1 when a model could not compute a value (HD solver failure): an error
V_XJ = 9        # jack position [m] written by the plant before each call (compressible HD)
V_CALLS = 10    # number of calls since reset
V_ITSUM = 11    # iterations summed over the calls since reset (mean = V_ITSUM/V_CALLS)
V_P1_PREV = 12  # HD: port pressures of the call before the last (the warm start's trend)
V_P2_PREV = 13
VS_SIZE = 14


def new_state(ps_mid: float = np.nan) -> np.ndarray:
    """A fresh valve state; ``ps_mid`` = (PS + PR)/2 is HD's initial port pressure."""
    vs = np.zeros(VS_SIZE)
    vs[V_P1] = ps_mid
    vs[V_P2] = ps_mid
    vs[V_P1_PREV] = ps_mid            # at rest: no trend
    vs[V_P2_PREV] = ps_mid
    return vs
