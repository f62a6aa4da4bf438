"""The EHA plant (paper Fig. 18): ECU, servovalve, fluid model and jack composed into one step,
and the compiled loops that run many steps in one call.

One step from t to t + DT, with inputs held over the step (zero-order hold):

1. the valve model turns the state at t (XS, QJ = AJ*DXJ) and PSR into P12;
2. the jack integrates under P12 and FR; the servovalve under the current Cor.

Both the ROS-free :func:`~.simulate.simulate` and the ROS plant node call :func:`plant_step`
(through :func:`run_steps` and :func:`run_tick`): the physics is one code path, which is why a
ROS run equals a ROS-free run to the last bit.
"""

from numba import njit

# The loops below take the valve model's compiled function as an argument, so numba compiles one
# specialisation per model. They are deliberately not cached on disk: numba's cache of functions
# with dispatcher arguments goes stale when a valve module changes ("underlying object has
# vanished"). Compiling costs about 1 s per model and process (see bench/README.md).

from .ecu import ecu_current
from .jack import jack_step
from .servovalve import S_DXJ, S_XJ, S_XS, servovalve_step
from .valve_state import V_FAIL, V_P1, V_P2, V_XJ

# columns of the rows written by run_steps (t is filled in by the caller)
OUT_COLUMNS = ('t', 'com', 'fr', 'psr', 'cor', 'xs', 'xj', 'dxj', 'p12', 'qj', 'p1', 'p2')
TICK_OUT = ('p12', 'qj', 'p1', 'p2')


@njit
def plant_step(valve_fn, s, vs, P, cor, fr, psr, integrate):
    """P12 and QJ at the state ``s`` (time t); then, if ``integrate``, advance ``s`` to t + DT.

    :param valve_fn: a registered valve model's compiled function
    :param s: plant state (:mod:`.servovalve` layout), updated in place
    :param vs: valve state (:mod:`.valve_state` layout), updated in place
    :param cor: servovalve current [A], held over the step
    :param fr: external load [N], held; :param psr: scheduled supply-return pressure [Pa], held;
        the valve sees ``PSR_scale`` of it (1 unless the supply_loss fault is injected)
    """
    qj = P.AJ * s[S_DXJ]
    vs[V_XJ] = s[S_XJ]
    p12 = valve_fn(s[S_XS], qj, psr * P.PSR_scale, P, vs)
    if integrate:
        jack_step(s, p12, fr, P)
        servovalve_step(s, cor, P)
    return p12, qj


@njit
def run_steps(valve_fn, s, vs, P_arr, seg, com, fr, psr, ecu_every, out_every, out):
    """Run ``len(com) - 1`` steps; the last input sample is the end instant, evaluated without
    integrating so that the last output row holds P12 at the end time.

    ``ecu_every`` = 0 evaluates the ECU every step (continuous); n > 0 samples it every n steps
    and holds Cor in between. Every ``out_every`` steps a row of :data:`OUT_COLUMNS` is written.
    ``P_arr`` stacks :meth:`~.params.EhaParams.kernel_array` rows, one per parameter segment
    (faults change parameters mid-run); ``seg[i]`` is the row in force on step i. Returns -1, or
    the index of the step at which the valve model failed.
    """
    n = com.shape[0] - 1
    row = 0
    cor = 0.0
    for i in range(n + 1):
        P = P_arr[seg[i]]
        if ecu_every == 0 or i % ecu_every == 0:
            cor = ecu_current(com[i], s[S_XJ], P)
        xs = s[S_XS]
        xj = s[S_XJ]
        dxj = s[S_DXJ]
        p12, qj = plant_step(valve_fn, s, vs, P, cor, fr[i], psr[i], i < n)
        if vs[V_FAIL] != 0.0:
            return i
        if i % out_every == 0:
            out[row, 1] = com[i]
            out[row, 2] = fr[i]
            out[row, 3] = psr[i]
            out[row, 4] = cor
            out[row, 5] = xs
            out[row, 6] = xj
            out[row, 7] = dxj
            out[row, 8] = p12
            out[row, 9] = qj
            out[row, 10] = vs[V_P1]
            out[row, 11] = vs[V_P2]
            row += 1
    return -1


@njit
def run_tick(valve_fn, s, vs, P_arr, cor, fr, psr, n_sub, out):
    """One control period of the ROS plant: ``n_sub`` steps with Cor, FR, PSR held.

    ``out`` receives :data:`TICK_OUT` at the start of the tick (the valve's response to the
    inputs in force from that instant). ``n_sub`` = 0 evaluates without integrating (the end
    instant of a run). Returns -1, or the sub-step at which the valve model failed.
    """
    P = P_arr[0]
    n = n_sub if n_sub > 0 else 1
    for j in range(n):
        p12, qj = plant_step(valve_fn, s, vs, P, cor, fr, psr, n_sub > 0)
        if vs[V_FAIL] != 0.0:
            return j
        if j == 0:
            out[0] = p12
            out[1] = qj
            out[2] = vs[V_P1]
            out[3] = vs[V_P2]
    return -1
