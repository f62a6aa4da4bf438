"""The one registry of servovalve fluid-dynamic models.

Every model maps (XS, QJ, PSR) to P12 with one shared compiled signature::

    fn(xs, qj, psr, P, vs) -> p12

``P`` is :class:`~servovalve_twin.physics.params.KernelParams` (SI units), ``vs`` the valve
state vector of :mod:`..valve_state` (warm starts in, diagnostics out). From Python, a
:class:`ValveModel` is called as ``model(xs, qj, psr, params, state=None) -> (p12, state,
info)`` (doc/design/MODELS.md section 9).

Everything model-specific lives in the model's file and its entry here: the compiled function,
its kernel constants, its initial state, its hand-over when switched to mid-run, its
diagnostics, whether it has port pressures, whether it may serve as a monitor model and with
which default thresholds. Nothing outside ``valves/`` tests a model's name.

Adding a model -- the contract the tests enforce on every entry:

1. write ``fn`` as a ``@jit`` function (:mod:`servovalve_twin.jitcache`) with the signature
   above, in SI units, in a file of this folder; it must return a finite P12 for any finite
   input, and may read or update only its documented ``vs`` slots (and the kernel slots
   ``VC0``.. it fills through ``constants``);
2. register it below in :data:`VALVE_MODELS` under the name users type (``valve_model:=NAME``),
   with the paper figure it reproduces and what differs from the defaults of
   :class:`ValveModel`, and add its branch to :func:`valve_p12` under its position in the
   registry (its ``id``);
3. the contract tests (``test/physics/test_valve_contract.py``) then run it at random points,
   through ``simulate``, in the stateful plant, across a mid-run switch, in a short ROS twin run and
   in its bag, with no further change.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from ...errors import ModelError
from ...jitcache import jit
from ..params import EhaParams
from ..valve_state import (V_CALLS, V_FAIL, V_ITSUM, V_MAXITER, V_NCAV, V_NONCONV, V_P12,
                           V_XJ, VS_SIZE, new_state)
from . import hd as _hd
from . import orifice as _sq
from . import simplified as _s


def _rest_state(params: EhaParams, xj: float = 0.0) -> np.ndarray:
    """A stateless model at rest: P12 = 0 (C4's warm start), no port pressures."""
    vs = new_state()
    vs[V_XJ] = xj
    return vs


def _keep_p12(vs: np.ndarray, old_vs: np.ndarray, old_has_ports: bool) -> None:
    """Switched to mid-run: start from the last P12 (C4's short run warm-starts from it)."""
    vs[V_P12] = old_vs[V_P12]


def _no_info(vs: np.ndarray) -> dict[str, Any]:
    return {}


def _no_constants(params: EhaParams) -> tuple[float, ...]:
    return ()


@dataclasses.dataclass(frozen=True)
class ValveModel:
    """A registered valve model: its compiled function and everything else that is its own."""

    name: str
    fn: Callable
    figure: str
    summary: str
    #: position in the registry: the compiled loops select the model by it (:func:`valve_p12`)
    id: int = -1
    has_ports: bool = False     # publishes P1/P2 (HD)
    iterative: bool = False     # counts iterations and non-converged calls (C4, HD)
    #: may serve as the monitor model (a fast simplified model; HD is the plant reference)
    monitor: bool = True
    #: runs faster per unit as a fleet (:func:`..fleet.simulate_many`) than alone: a step
    #: whose latency chain is long (SQ's square roots: 1.32 x at 3 and 8 units, bench_physics)
    #: gains from interleaved units; a short one kept in registers alone loses (C2: 0.73 x;
    #: HD: 0.90-1.02 x). The fits run their batches as fleets for these models only
    fleet_pays: bool = False
    #: params -> the kernel constants VC0.. this model reads (computed once, not per step)
    constants: Callable[[EhaParams], tuple[float, ...]] = _no_constants
    #: (params, xj) -> the valve state at rest
    rest_state: Callable[[EhaParams, float], np.ndarray] = _rest_state
    #: (new state, old state, old model has ports) -> None: what it takes over mid-run
    handover: Callable[[np.ndarray, np.ndarray, bool], None] = _keep_p12
    #: valve state -> diagnostics of the last call, by name
    last_info: Callable[[np.ndarray], dict[str, Any]] = _no_info

    def __call__(self, xs: float, qj: float, psr: float, params: EhaParams,
                 state: np.ndarray | None = None) -> tuple[float, np.ndarray, dict[str, Any]]:
        """Evaluate once from Python: ``(p12, new_state, info)``; ``state`` is not modified."""
        vs = self.initial_state(params) if state is None else np.array(state, dtype=float)
        if vs.shape != (VS_SIZE,):
            raise ModelError(f'valve state must have {VS_SIZE} entries, got shape {vs.shape}')
        for label, v in (('XS', xs), ('QJ', qj), ('PSR', psr)):
            if not math.isfinite(v):
                raise ModelError(f'{label} must be finite, got {v!r}')
        p12 = float(self.fn(float(xs), float(qj), float(psr), self.kernel(params), vs))
        if vs[V_FAIL]:
            raise ModelError(f'valve model {self.name} failed to converge at XS={xs!r} m, '
                             f'QJ={qj!r} m^3/s, PSR={psr!r} Pa')
        return p12, vs, self.info(vs)

    def kernel(self, params: EhaParams):
        """The compiled physics' parameter tuple for this model (its constants filled in)."""
        return params.kernel(self.constants(params))

    def kernel_array(self, params: EhaParams) -> np.ndarray:
        """:meth:`kernel` as the one-row structured array the compiled loops take."""
        return params.kernel_array(self.constants(params))

    def initial_state(self, params: EhaParams, xj: float = 0.0) -> np.ndarray:
        """The valve state at rest (jack at ``xj``)."""
        return self.rest_state(params, xj)

    def take_over(self, params: EhaParams, old: 'ValveModel', old_vs: np.ndarray,
                  xj: float) -> np.ndarray:
        """This model's state when it replaces ``old`` mid-run with the jack at ``xj``."""
        vs = self.initial_state(params, xj)
        self.handover(vs, old_vs, old.has_ports)
        return vs

    def info(self, vs: np.ndarray) -> dict[str, Any]:
        """Diagnostics of the last call, by name."""
        return self.last_info(vs)

    def run_totals(self, vs: np.ndarray) -> dict[str, Any]:
        """Counters over a run (iterative models): calls, largest iteration count, calls that
        did not converge, calls with a cavitating port."""
        if not self.iterative:
            return {}
        calls = int(vs[V_CALLS])
        return dict(valve_calls=calls, max_iterations=int(vs[V_MAXITER]),
                    mean_iterations=float(vs[V_ITSUM]) / calls if calls else 0.0,
                    nonconverged_calls=int(vs[V_NONCONV]), cavitating_calls=int(vs[V_NCAV]))


#: name -> model. The names are those of the command line, the ROS parameter and the bags.
VALVE_MODELS: dict[str, ValveModel] = {m.name: dataclasses.replace(m, id=i) for i, m in enumerate((
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
               iterative=True, last_info=_s.c4_info),
    ValveModel('SQ', _sq.model_sq, 'beyond the paper (issue 6)',
               'explicit four-edge orifice law: sqrt load droop, P12 > PSR when over-run',
               constants=_sq.sq_constants, fleet_pays=True),
    ValveModel('HD', _hd.hd_solve, 'Fig. 23 reference',
               'four-edge valve: laps, clearance, orifice + laminar gap, port continuity',
               has_ports=True, iterative=True, monitor=False,
               rest_state=_hd.hd_initial_state, handover=_hd.hd_handover,
               last_info=_hd.hd_info),
))}

VALVE_MODEL_NAMES = tuple(VALVE_MODELS)


@jit
def valve_p12(model_id, xs, qj, psr, P, vs):
    """P12 of the registered model with ``id`` = ``model_id`` (its ``fn``, same signature).

    The compiled loops take the model as this integer rather than as its function object: a
    loop with a function argument is compiled again in every process (numba keys such
    arguments on the object's identity, so its disk cache never hits) and costs ~5 us per call
    to pass one in; an integer lets one loop, cached on disk, serve every model, with each
    model's code inlined in its branch. The branches follow the registry's order (the contract
    test checks each one against its model's ``fn``); an id without a branch fails the step.
    """
    if model_id == 0:
        return _s.linear(xs, qj, psr, P, vs)
    if model_id == 1:
        return _s.saturated(xs, qj, psr, P, vs)
    if model_id == 2:
        return _s.saturated_downstream(xs, qj, psr, P, vs)
    if model_id == 3:
        return _s.linear_leakage(xs, qj, psr, P, vs)
    if model_id == 4:
        return _s.model_a(xs, qj, psr, P, vs)
    if model_id == 5:
        return _s.model_b(xs, qj, psr, P, vs)
    if model_id == 6:
        return _s.model_c1(xs, qj, psr, P, vs)
    if model_id == 7:
        return _s.model_c2(xs, qj, psr, P, vs)
    if model_id == 8:
        return _s.model_c3(xs, qj, psr, P, vs)
    if model_id == 9:
        return _s.model_c4(xs, qj, psr, P, vs)
    if model_id == 10:
        return _sq.model_sq(xs, qj, psr, P, vs)
    if model_id == 11:
        return _hd.hd_solve(xs, qj, psr, P, vs)
    vs[V_FAIL] = 1.0
    return 0.0
#: the models that may serve as the monitor model
MONITOR_MODEL_NAMES = tuple(n for n, m in VALVE_MODELS.items() if m.monitor)


def get_valve_model(name: str) -> ValveModel:
    """The registered model called ``name``; an unknown name lists the valid ones."""
    try:
        return VALVE_MODELS[name]
    except (KeyError, TypeError):
        raise ModelError(f'unknown valve model {name!r}; expected one of '
                         f'{list(VALVE_MODEL_NAMES)}') from None


def get_monitor_model(name: str) -> ValveModel:
    """A registered model that may serve as the monitor model, or a one-line refusal."""
    model = get_valve_model(name)
    if not model.monitor:
        raise ModelError(f'the monitor runs a simplified model, not {name!r}; expected one of '
                         f'{list(MONITOR_MODEL_NAMES)}')
    return model
