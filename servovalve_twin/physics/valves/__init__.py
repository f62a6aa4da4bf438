"""The one registry of servovalve fluid-dynamic models.

Every model maps (XS, QJ, PSR) to P12 with one shared compiled signature::

    fn(xs, qj, psr, P, vs) -> p12

``P`` is :class:`~servovalve_twin.physics.params.KernelParams` (SI units), ``vs`` the valve
state vector of :mod:`..valve_state` (warm starts in, diagnostics out). From Python, a
:class:`ValveModel` is called as ``model(xs, qj, psr, params, state=None) -> (p12, state,
info)`` (MODELS.md section 9).

Adding a model -- the contract the tests enforce on every entry:

1. write ``fn`` as an ``@njit`` function with the signature above, in SI units; it must return
   a finite P12 for any finite input, and may read or update only its documented ``vs`` slots;
2. register it below in :data:`VALVE_MODELS` under the name users type (``valve_model:=NAME``),
   with the paper figure it reproduces and whether it yields port pressures P1/P2;
3. the contract tests (``test/test_valve_contract.py``) then run it at random points, through
   a whole scenario, in the ROS plant and in bags, with no further change.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from ...errors import ModelError
from ..params import EhaParams
from . import simplified as _s
from .orifice import model_sq
from ..valve_state import (V_CAV, V_FAIL, V_ITER, V_NONCONV, V_P1, V_P2, V_XJ, VS_SIZE,
                           new_state)
from ..hd import hd_solve


@dataclasses.dataclass(frozen=True)
class ValveModel:
    """A registered valve model: its compiled function and what users need to know about it."""

    name: str
    fn: Callable
    figure: str
    summary: str
    has_ports: bool = False     # publishes P1/P2 (HD)
    iterative: bool = False     # reports iteration counts (C4, HD)

    def __call__(self, xs: float, qj: float, psr: float, params: EhaParams,
                 state: np.ndarray | None = None) -> tuple[float, np.ndarray, dict[str, Any]]:
        """Evaluate once from Python: ``(p12, new_state, info)``; ``state`` is not modified."""
        vs = self.initial_state(params) if state is None else np.array(state, dtype=float)
        if vs.shape != (VS_SIZE,):
            raise ModelError(f'valve state must have {VS_SIZE} entries, got shape {vs.shape}')
        for label, v in (('XS', xs), ('QJ', qj), ('PSR', psr)):
            if not math.isfinite(v):
                raise ModelError(f'{label} must be finite, got {v!r}')
        p12 = float(self.fn(float(xs), float(qj), float(psr), params.kernel(), vs))
        if vs[V_FAIL]:
            raise ModelError(f'valve model {self.name} failed to converge at XS={xs!r} m, '
                             f'QJ={qj!r} m^3/s, PSR={psr!r} Pa')
        return p12, vs, self.info(vs)

    def initial_state(self, params: EhaParams, xj: float = 0.0) -> np.ndarray:
        """State at rest: P12 = 0; HD ports at (PS + PR)/2 = PR + PSRN/2."""
        vs = new_state(params.PR + 0.5 * params.PSRN)
        vs[V_XJ] = xj
        return vs

    def info(self, vs: np.ndarray) -> dict[str, Any]:
        """Diagnostics of the last call, by name."""
        out: dict[str, Any] = {}
        if self.iterative:
            out['iterations'] = int(vs[V_ITER])
            out['nonconverged_calls'] = int(vs[V_NONCONV])
        if self.has_ports:
            out['p1'] = float(vs[V_P1])
            out['p2'] = float(vs[V_P2])
            out['cavitation'] = int(vs[V_CAV])
        return out


#: name -> model. The names are those of the command line, the ROS parameter and the bags.
VALVE_MODELS: dict[str, ValveModel] = {m.name: m for m in (
    ValveModel('linear', _s.linear, 'Fig. 4', 'P12 = GPN*XS - GPQ*QJ (never stalls)'),
    ValveModel('saturated', _s.saturated, 'Fig. 5', 'P12 = sat(GPN*XS, PSR) - GPQ*QJ'),
    ValveModel('saturated_downstream', _s.saturated_downstream, 'Fig. 11',
               'P12 = sat(GPN*XS - GPQ*QJ, PSR)'),
    ValveModel('linear_leakage', _s.linear_leakage, 'Figs. 6-8',
               'P12 = (GPN*XS - GPQ*QJ)/(1 + k)'),
    ValveModel('A', _s.model_a, 'Fig. 9', 'P12 = U/(1 + k), no saturation'),
    ValveModel('B', _s.model_b, 'Fig. 10', 'P12 = (sat(PSR*XS/XSS, PSR) - GPQ*QJ)/(1 + k)'),
    ValveModel('C1', _s.model_c1, 'Fig. 12', 'P12 = sat(U, PSR)/(1 + k)'),
    ValveModel('C2', _s.model_c2, 'Fig. 13', 'P12 = sat(U/(1 + k), PSR)'),
    ValveModel('C3', _s.model_c3, 'Figs. 14-15', 'P12 = sat(U, PSR)/(1 + k*XSS/max(|XS|, XSS))'),
    ValveModel('C4', _s.model_c4, 'Figs. 16-17',
               'fixed point of P12 = sat(U - k*P12, PSR) by a pseudo-dynamic short run',
               iterative=True),
    ValveModel('SQ', model_sq, 'beyond the paper (issue 6)',
               'explicit four-edge orifice law: sqrt load droop, P12 > PSR when over-run'),
    ValveModel('HD', hd_solve, 'Fig. 23 reference',
               'four-edge valve: laps, clearance, orifice + laminar gap, port continuity',
               has_ports=True, iterative=True),
)}

VALVE_MODEL_NAMES = tuple(VALVE_MODELS)


def get_valve_model(name: str) -> ValveModel:
    """The registered model called ``name``; an unknown name lists the valid ones."""
    try:
        return VALVE_MODELS[name]
    except (KeyError, TypeError):
        raise ModelError(f'unknown valve model {name!r}; expected one of '
                         f'{list(VALVE_MODEL_NAMES)}') from None
