"""ECU position loop (paper Fig. 18): Err = Com - XJ, Cor = sat(GAP*Err, CorM)."""

import types

from ..jitcache import jit
from .valves.simplified import sat


@jit
def ecu_current(com, xj, P):
    """Servovalve current Cor [A] for command ``com`` [m] and measured jack position ``xj`` [m].

    The null-bias fault CorB is *not* added here: it is a valve defect, entering the torque motor
    after the ECU's saturation (see :func:`~.servovalve.servovalve_step`).
    """
    return sat(P.GAP * (com - xj), P.CorM)


def _interpreted(dispatcher):
    """A compiled function's own source run by the interpreter, with the compiled helpers it
    calls (``sat``) replaced by theirs: calling a compiled helper from Python costs ~1 us,
    more than the ECU law itself."""
    fn = dispatcher.py_func
    return types.FunctionType(fn.__code__, {**fn.__globals__, 'sat': sat.py_func}, fn.__name__)


#: :func:`ecu_current` run by the interpreter (the ROS ECU, the monitor, EhaPlant.control)
ecu_current_py = _interpreted(ecu_current)


class EcuLaw:
    """The ECU law with given parameters, called from Python (the ROS ECU and the monitor): the
    source of the compiled :func:`ecu_current`, run by the interpreter -- a compiled call costs
    more to enter than the law costs to compute, and IEEE arithmetic makes both bit-identical
    (tested)."""

    def __init__(self, params):
        self.params = params
        self._kernel = params.kernel()

    def __call__(self, com: float, xj: float) -> float:
        return float(ecu_current_py(float(com), float(xj), self._kernel))
