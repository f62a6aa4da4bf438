"""ECU position loop (paper Fig. 18): Err = Com - XJ, Cor = sat(GAP*Err, CorM)."""

from numba import njit

from .valves.simplified import sat


@njit(cache=True)
def ecu_current(com, xj, P):
    """Servovalve current Cor [A] for command ``com`` [m] and measured jack position ``xj`` [m].

    The null-bias fault CorB is *not* added here: it is a valve defect, entering the torque motor
    after the ECU's saturation (see :func:`~.servovalve.servovalve_step`).
    """
    return sat(P.GAP * (com - xj), P.CorM)
