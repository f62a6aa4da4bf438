"""The EHA plant (paper Fig. 18): ECU, servovalve, fluid model and jack composed into one step,
and the compiled loops that run many steps in one call.

One step from t to t + DT, with inputs held over the step (zero-order hold):

1. the valve model turns the state at t (XS, QJ = AJ*DXJ) and PSR into P12;
2. the jack integrates under P12 and FR; the servovalve under the current Cor.

Both the ROS-free :func:`~.simulate.simulate` (through :func:`run_steps_for`) and the ROS
plant node (through :func:`run_tick`) take this step: :func:`plant_step`, which the loops of
:func:`run_steps_for` write out in their body because as a call there it ran twice as slow
(measured; numba did not keep the state in registers across it). The tests hold the two to
the last bit (a ROS run equals a ROS-free run, every column).

One loop per valve model (:func:`jit_run_steps_for`): with the model's id an argument, the
loop called :func:`valve_p12` out of line every step (its arguments on the stack, every live
register spilled, a reference count taken and dropped on ``vs``). There the id is a constant
of the loop (a closure variable; numba keys the cache on its value, so each model's loop is
cached on its own) and the valve function is inlined: the other models' branches fold away.
The arithmetic is that of :func:`plant_step`, in the same order, so the rows are
bit-identical (tested against :func:`run_tick`).
"""

import functools

from ..jitcache import jit
from .ecu import ecu_current
from .jack import jack_advance, jack_step
from .sensors import C_ON, SENSED, sense
from .servovalve import (S_DXF, S_DXJ, S_XF, S_XJ, S_XS, servovalve_advance,
                         servovalve_step)
from .signals import NAMES
from .valve_state import V_FAIL, V_P1, V_P2, V_XJ
from .valves import valve_p12

#: valve_p12 inlined where the id is a constant (run_steps_for): the other branches fold away
valve_p12_inline = jit(inline='always')(valve_p12.py_func)

# The loops select the valve model by its registry id (valves.valve_p12: an argument of
# run_tick, a closure constant of run_steps_for's loops), so they are compiled once, cached on
# disk, and loaded by every later process (servovalve_twin.jitcache).

# columns of the rows written by run_steps_for's loops
OUT_COLUMNS = ('t',) + NAMES
#: with sensors, the rows carry the sensed signals' readings in their own columns and the truth
#: of each in these, after :data:`OUT_COLUMNS`
TRUTH_COLUMNS = tuple(f'{s}_true' for s in SENSED)
#: the columns of the sensed signals in the rows, :data:`~.sensors.SENSED` order
_SENSED_COLUMNS = tuple(OUT_COLUMNS.index(s) for s in SENSED)
_TRUTH_START = len(OUT_COLUMNS)
TICK_OUT = ('p12', 'qj', 'p1', 'p2')


@jit
def plant_step(model_id, s, vs, P, cor, fr, psr, integrate):
    """P12 and QJ at the state ``s`` (time t); then, if ``integrate``, advance ``s`` to t + DT.

    :param model_id: a registered valve model's ``id``
    :param s: plant state (:mod:`.servovalve` layout), updated in place
    :param vs: valve state (:mod:`.valve_state` layout), updated in place
    :param cor: servovalve current [A], held over the step
    :param fr: external load [N], held; :param psr: scheduled supply-return pressure [Pa], held;
        the valve sees ``PSR_scale`` of it (1 unless the supply_loss fault is injected)
    """
    qj = P.AJ * s[S_DXJ]
    vs[V_XJ] = s[S_XJ]
    p12 = valve_p12(model_id, s[S_XS], qj, psr * P.PSR_scale, P, vs)
    if integrate:
        jack_step(s, p12, fr, P)
        servovalve_step(s, cor, P)
    return p12, qj


def run_steps_for(model_id: int, sensed: bool = False):
    """The step loop of the valve model with registry ``id`` = ``model_id``: compiled ahead of
    time where the module of the current physics is built (:mod:`servovalve_twin.aot`), else
    :func:`jit_run_steps_for`'s -- the same source, the same bytes out (tested)."""
    from ..jitcache import aot_loop
    return aot_loop('steps', model_id, sensed) or jit_run_steps_for(model_id, sensed)


@jit(inline='always')
def write_row(row, t, com, fr, psr, cor, xs, xj, dxj, p12, qj, p1, p2):
    """One output row of :data:`OUT_COLUMNS` (inlined into the loops: copies only)."""
    row[0] = t
    row[1] = com
    row[2] = fr
    row[3] = psr
    row[4] = cor
    row[5] = xs
    row[6] = xj
    row[7] = dxj
    row[8] = p12
    row[9] = qj
    row[10] = p1
    row[11] = p2


@jit(inline='always')
def write_readings(row, spec, held):
    """With sensors: each sensed signal's truth into :data:`TRUTH_COLUMNS`, and its reading
    in its own column where a sensor reads it."""
    for m, col in enumerate(_SENSED_COLUMNS):
        row[_TRUTH_START + m] = row[col]
        if spec[m, C_ON] != 0.0:
            row[col] = held[m]


@functools.lru_cache(maxsize=None)
def jit_run_steps_for(model_id: int, sensed: bool = False):
    """The step loop of the valve model with registry ``id`` = ``model_id`` (built once per
    model and process, its machine code loaded from numba's disk cache); ``sensed``: the loop
    with sensors (:mod:`.sensors`), whose ECU reads the measured XJ -- a loop of its own, so
    that the loop without them is the one it always was (its branches fold away). Why one
    loop per model: the module docstring.
    """
    def run_steps(s, vs, P_arr, seg_start, com, fr, psr, i0, n, ecu_every, out_every,
                  carry, out, out_dt, spec, keys, held, sense_every):
        """Run the steps ``i0 .. i0 + len(com) - 1`` of a run of ``n`` steps; called chunk
        after chunk, so that a run's inputs are never held whole. Step ``n`` is the end
        instant, evaluated without integrating so that the last output row holds P12 at the
        end time.

        ``com``, ``fr``, ``psr``: the inputs of those steps. ``ecu_every`` = 0 evaluates the
        ECU every step (continuous); k > 0 samples it every k steps and holds Cor in between.
        Every ``out_every`` steps, row ``i // out_every`` of :data:`OUT_COLUMNS` is written to
        ``out`` (t = row*``out_dt``). ``P_arr`` stacks :meth:`~.params.EhaParams.kernel_array`
        rows, one per parameter segment (faults change parameters mid-run); row k is in force
        from step ``seg_start[k]`` on. ``carry`` = [Cor, segment] is kept between chunks.
        With sensors: ``spec``, ``keys`` (:meth:`~.sensors.Sensors.table`) and the readings
        held between samples, ``held`` (kept between chunks), taken on the grid of
        ``sense_every`` steps (the control period: every sensor's period is a multiple of
        it); the rows then carry the readings in the sensed signals' columns and the truth in
        :data:`TRUTH_COLUMNS`. A signal without a sensor reads its truth.
        Returns -1, or the index of the step at which the valve model failed.
        """
        cor = carry[0]
        k = int(carry[1])
        n_seg = seg_start.shape[0]
        # the plant state in locals for the chunk (registers), back into ``s`` at its end
        xf, dxf, xs, xj, dxj = s[S_XF], s[S_DXF], s[S_XS], s[S_XJ], s[S_DXJ]
        for j in range(com.shape[0]):
            i = i0 + j
            while k + 1 < n_seg and i >= seg_start[k + 1]:
                k += 1
            P = P_arr[k]
            on_grid = False
            if sensed:
                # the sensors read the state first: the ECU's XJ is the measured one
                on_grid = i % sense_every == 0
                if on_grid:
                    sense(0, xs, i, spec, keys, held)
                    sense(1, xj, i, spec, keys, held)
                    sense(2, dxj, i, spec, keys, held)
                if ecu_every == 0 or i % ecu_every == 0:
                    cor = ecu_current(com[j], held[1] if spec[1, C_ON] != 0.0 else xj, P)
            elif ecu_every == 0 or i % ecu_every == 0:
                cor = ecu_current(com[j], xj, P)
            # plant_step, written out (see the module docstring)
            qj = P.AJ * dxj
            vs[V_XJ] = xj
            p12 = valve_p12_inline(model_id, xs, qj, psr[j] * P.PSR_scale, P, vs)
            if on_grid:
                sense(3, p12, i, spec, keys, held)
                sense(4, vs[V_P1], i, spec, keys, held)
                sense(5, vs[V_P2], i, spec, keys, held)
            # the row's values are those at the step's start: kept before integrating
            xs0, xj0, dxj0 = xs, xj, dxj
            if i < n:
                xj, dxj = jack_advance(xj, dxj, p12, fr[j], P)
                xf, dxf, xs = servovalve_advance(xf, dxf, xs, cor, P)
            if vs[V_FAIL] != 0.0:
                s[S_XF], s[S_DXF], s[S_XS], s[S_XJ], s[S_DXJ] = xf, dxf, xs, xj, dxj
                return i
            if i % out_every == 0:
                row = i // out_every
                write_row(out[row], row * out_dt, com[j], fr[j], psr[j], cor, xs0, xj0, dxj0,
                          p12, qj, vs[V_P1], vs[V_P2])
                if sensed:
                    write_readings(out[row], spec, held)
        s[S_XF], s[S_DXF], s[S_XS], s[S_XJ], s[S_DXJ] = xf, dxf, xs, xj, dxj
        carry[0] = cor
        carry[1] = k
        return -1

    return jit(own_cache_name(run_steps, f'm{model_id}' + ('_sensed' if sensed else '')))


def own_cache_name(fn, tag: str):
    """``fn`` named apart per closure (numba names a cached function's files by its
    qualified name): the loops of all models and variants shared one index file, and two
    processes compiling two of them at once could each give its machine code the same data
    file -- the index then handed one loop another's code (numba picks a data file's name
    from the index it read, and does not check it on loading)."""
    fn.__qualname__ = f'{fn.__qualname__}_{tag}'
    return fn


def tick_for(model_id: int):
    """:func:`run_tick` for a valve model: compiled ahead of time (:mod:`~..aot`) where the
    module of the current physics is built, else the JIT's -- the same arguments."""
    from ..jitcache import aot_loop
    return aot_loop('tick', model_id) or run_tick


@jit
def run_tick(model_id, s, vs, P_arr, cor, fr, psr, n_sub, out):
    """One control period of the ROS plant: ``n_sub`` steps with Cor, FR, PSR held.

    ``out`` receives :data:`TICK_OUT` at the start of the tick (the valve's response to the
    inputs in force from that instant). ``n_sub`` = 0 evaluates without integrating (the end
    instant of a run). Returns -1, or the sub-step at which the valve model failed.
    """
    P = P_arr[0]
    n = n_sub if n_sub > 0 else 1
    for j in range(n):
        p12, qj = plant_step(model_id, s, vs, P, cor, fr, psr, n_sub > 0)
        if vs[V_FAIL] != 0.0:
            return j
        if j == 0:
            out[0] = p12
            out[1] = qj
            out[2] = vs[V_P1]
            out[3] = vs[V_P2]
    return -1
