"""ECU position loop (paper Fig. 18): Err = Com - XJ, Cor = sat(GAP*Err, CorM)."""

from ..jitcache import jit

from .valves.simplified import sat


@jit
def ecu_current(com, xj, P):
    """Servovalve current Cor [A] for command ``com`` [m] and measured jack position ``xj`` [m].

    The null-bias fault CorB is *not* added here: it is a valve defect, entering the torque motor
    after the ECU's saturation (see :func:`~.servovalve.servovalve_step`).
    """
    return sat(P.GAP * (com - xj), P.CorM)


class EcuLaw:
    """The ECU law with given parameters, called from Python (the ROS ECU and the monitor): the
    source of the compiled :func:`ecu_current`, run by the interpreter -- a compiled call costs
    more to enter than the law costs to compute, and IEEE arithmetic makes both bit-identical
    (tested)."""

    def __init__(self, params):
        self.params = params
        self._kernel = params.kernel()

    def __call__(self, com: float, xj: float) -> float:
        return float(ecu_current.py_func(float(com), float(xj), self._kernel))
