"""A fleet in one compiled call: :func:`simulate_many` runs N units -- each with its own
parameters, scheduled faults and initial state -- on one scenario's inputs, the steps outside
and the units inside, so that the units' independent chains of arithmetic overlap in the CPU
(a unit's step is a chain of dependent divisions and square roots: latency, not throughput,
bounds one run). Each unit's rows are those :func:`~.simulate.simulate` gives it alone, bit
for bit (tested): the diagnosis' Jacobians and multi-start screens, whose runs differ only in
their parameters, run as one fleet.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ModelError, ParameterError
from ..jitcache import jit
from .ecu import ecu_current
from .jack import jack_advance
from .plant import OUT_COLUMNS, own_cache_name, valve_p12_inline
from .scenario import GridBuffers, Scenario, as_scenario
from .servovalve import PLANT_STATE, S_DXF, S_DXJ, S_SIZE, S_XF, S_XJ, S_XS, servovalve_advance
from .simulate import (CHUNK_STEPS, CSV_COLUMNS, OUTPUT_PERIOD_NS, PORT_COLUMNS, RunResult,
                       _fault_segments, effective_params, steps_per)
from .valve_state import V_FAIL, V_P1, V_P2, V_XJ
from .valves import get_valve_model

#: the most units in one call (the output rows of each are held at once)
MAX_UNITS = 1024


def run_fleet_for(model_id: int):
    """The fleet loop of the valve model with registry id ``model_id``: compiled ahead of time
    where the module of the current physics is built (:mod:`servovalve_twin.aot`), else
    :func:`jit_run_fleet_for`'s."""
    from ..jitcache import aot_loop
    return aot_loop('fleet', model_id) or jit_run_fleet_for(model_id)


@functools.lru_cache(maxsize=None)
def jit_run_fleet_for(model_id: int):
    """The fleet loop of the valve model with registry id ``model_id`` (a closure constant,
    as :func:`~.plant.run_steps_for`'s; the arithmetic of each unit's step is that loop's, in
    the same order)."""
    def run_fleet(s, vs, P_arr, seg_start, com, fr, psr, i0, n, ecu_every, out_every,
                  carry, out, out_dt, failed):
        """Steps ``i0 .. i0 + len(com) - 1`` of every unit ``u``: state ``s[u]``, valve state
        ``vs[u]``, parameter segments ``P_arr[u]`` from steps ``seg_start[u]`` (padded with
        segments that never start), ``carry[u]`` = [Cor, segment], rows into ``out[u]``. A
        unit whose valve model fails stops there: ``failed[u]`` = the step (else -1)."""
        n_units = s.shape[0]
        n_seg = seg_start.shape[1]
        for j in range(com.shape[0]):
            i = i0 + j
            for u in range(n_units):
                if failed[u] >= 0:
                    continue
                k = int(carry[u, 1])
                while k + 1 < n_seg and i >= seg_start[u, k + 1]:
                    k += 1
                carry[u, 1] = k
                P = P_arr[u, k]
                xf = s[u, S_XF]
                dxf = s[u, S_DXF]
                xs = s[u, S_XS]
                xj = s[u, S_XJ]
                dxj = s[u, S_DXJ]
                if ecu_every == 0 or i % ecu_every == 0:
                    carry[u, 0] = ecu_current(com[j], xj, P)
                cor = carry[u, 0]
                qj = P.AJ * dxj
                vsu = vs[u]
                vsu[V_XJ] = xj
                p12 = valve_p12_inline(model_id, xs, qj, psr[j] * P.PSR_scale, P, vsu)
                if i < n:
                    s[u, S_XJ], s[u, S_DXJ] = jack_advance(xj, dxj, p12, fr[j], P)
                    s[u, S_XF], s[u, S_DXF], s[u, S_XS] = servovalve_advance(xf, dxf, xs,
                                                                             cor, P)
                if vsu[V_FAIL] != 0.0:
                    failed[u] = i
                    continue
                if i % out_every == 0:
                    row = i // out_every
                    out[u, row, 0] = row * out_dt
                    out[u, row, 1] = com[j]
                    out[u, row, 2] = fr[j]
                    out[u, row, 3] = psr[j]
                    out[u, row, 4] = cor
                    out[u, row, 5] = xs
                    out[u, row, 6] = xj
                    out[u, row, 7] = dxj
                    out[u, row, 8] = p12
                    out[u, row, 9] = qj
                    out[u, row, 10] = vsu[V_P1]
                    out[u, row, 11] = vsu[V_P2]
        return 0

    return jit(own_cache_name(run_fleet, f'm{model_id}'))


def _segment_arrays(segs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Each unit's parameter segments (kernels and start steps) as the compiled loop's two
    arrays, one row a unit: a unit of fewer segments repeats its last kernel, never
    started."""
    n_seg = max(len(st) for _, st in segs)
    P_arr = np.empty((len(segs), n_seg), dtype=segs[0][0].dtype)
    seg_start = np.full((len(segs), n_seg), np.iinfo(np.int64).max, dtype=np.int64)
    for u, (kern, st) in enumerate(segs):
        P_arr[u, :len(st)] = kern
        P_arr[u, len(st):] = kern[-1]
        seg_start[u, :len(st)] = st
    return P_arr, seg_start


def simulate_many(valve_model: str, scenario: Scenario | Mapping,
                  params: Sequence[Any], *, ecu_period: float | None = None,
                  initial: Mapping[str, float] | None = None,
                  faults: Sequence[Sequence[Mapping[str, Any]]] | None = None,
                  failed: str = 'raise') -> list[RunResult | None]:
    """Run ``scenario``'s inputs on ``len(params)`` units in one compiled call.

    :param params: each unit's parameters (:class:`~.params.EhaParams`, whole)
    :param faults: each unit's scheduled faults (the scenario's ``faults`` schema) instead of
        the scenario's own; None: the scenario's for every unit
    :param initial: the plant state at t = 0 by name, for every unit (as :func:`simulate`'s)
    :param failed: 'raise' a :class:`ModelError` naming the first unit whose valve model
        failed, or give 'none' for it
    :returns: per unit, the :class:`RunResult` :func:`~.simulate.simulate` gives it alone
    """
    model = get_valve_model(valve_model)
    scn = as_scenario(scenario)
    if scn.sensors:
        raise ParameterError('simulate_many runs ideal sensors only (a fit simulates what '
                             'the unit is, not what its sensors read)')
    if failed not in ('raise', 'none'):
        raise ParameterError(f"failed must be 'raise' or 'none', got {failed!r}")
    n_units = len(params)
    if not 1 <= n_units <= MAX_UNITS:
        raise ParameterError(f'simulate_many runs 1 to {MAX_UNITS} units, got {n_units}')
    if faults is not None and len(faults) != n_units:
        raise ParameterError(f'{len(faults)} fault schedules for {n_units} units')
    units = [effective_params(scn, None, p) for p in params]
    dt_ns = units[0].dt_ns
    if any(p.dt_ns != dt_ns for p in units):
        raise ParameterError('the units of a fleet share one DT')
    p0 = units[0]
    out_every = steps_per(OUTPUT_PERIOD_NS * 1e-9, p0, 'the 1 ms output period')
    ecu_every = 0 if ecu_period is None else steps_per(ecu_period, p0, 'the ECU period')
    n_steps = scn.duration_ns // dt_ns
    if n_steps * dt_ns != scn.duration_ns:
        raise ParameterError(f'duration {scn.duration} s is not a whole number of DT')
    n_rows = n_steps // out_every + 1
    unit_scns = [scn if faults is None else dataclasses.replace(scn, faults=tuple(f))
                 for f in (faults or [None] * n_units)]
    P_arr, seg_start = _segment_arrays([_fault_segments(model, us, p)
                                        for us, p in zip(unit_scns, units)])
    s = np.zeros((n_units, S_SIZE))
    for name, value in (initial or {}).items():
        if name not in PLANT_STATE:
            raise ParameterError(f'initial: unknown plant state {name!r}; expected some of '
                                 f'{list(PLANT_STATE)}')
        s[:, PLANT_STATE.index(name)] = float(value)
    vs = np.stack([model.initial_state(p) for p in units])
    out = np.full((n_units, n_rows, len(OUT_COLUMNS)), np.nan)
    carry = np.zeros((n_units, 2))
    fail = np.full(n_units, -1, dtype=np.int64)
    run = run_fleet_for(model.id)
    buffers = GridBuffers.reused(min(CHUNK_STEPS, n_steps + 1))
    for i0 in range(0, n_steps + 1, CHUNK_STEPS):
        m = min(CHUNK_STEPS, n_steps + 1 - i0)
        com, fr, psr = scn.grid_inputs(i0 * dt_ns, dt_ns, m, buffers)   # as simulate() does
        run(s, vs, P_arr, seg_start, com, fr, psr, i0, n_steps, ecu_every, out_every, carry,
            out, OUTPUT_PERIOD_NS * 1e-9, fail)
        if np.all(fail >= 0):
            break
    return _results(model, unit_scns, units, out, fail, failed, ecu_period, vs, n_steps)


def _results(model, unit_scns, units, out, fail, failed, ecu_period, vs, n_steps
             ) -> list[RunResult | None]:
    """Each unit's :class:`RunResult` from the fleet's output rows (None, or a
    :class:`ModelError` with ``failed`` 'raise', for a unit whose valve model failed)."""
    cols = CSV_COLUMNS + (PORT_COLUMNS if model.has_ports else ())
    results: list[RunResult | None] = []
    for u, p in enumerate(units):
        if fail[u] >= 0:
            if failed == 'raise':
                raise ModelError(f'unit {u}: valve model {model.name} failed to converge at '
                                 f't = {fail[u] * p.DT:.6f} s')
            results.append(None)
            continue
        results.append(RunResult(
            valve_model=model.name, scenario=unit_scns[u], params=p,
            signals={c: out[u, :, OUT_COLUMNS.index(c)].copy() for c in cols},
            ecu_period=ecu_period, info=dict(model.run_totals(vs[u]), steps=n_steps)))
    return results


__all__ = ['simulate_many', 'run_fleet_for', 'jit_run_fleet_for', 'MAX_UNITS']
