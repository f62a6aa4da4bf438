"""The EHA as a NASA progpy ``PrognosticsModel``: progpy's state estimators (particle filter,
unscented Kalman filter) and its Monte-Carlo predictor run on the twin's compiled physics.

``pip install 'servovalve_twin[progpy]'`` (progpy is an optional extra)::

    from servovalve_twin.progpy import EhaModel
    m = EhaModel(valve_model='SQ', degradation=['leakage_growth'],
                 process_noise={'leakage_growth': 2.0})
    x0 = m.initialize()
    x1 = m.next_state(x0, m.InputContainer({'com': 0.02, 'fr': 0.0, 'psr': 2e7}), 1e-3)

The model (discrete in time, vectorized over particles):

- **inputs** ``com`` [m], ``fr`` [N], ``psr`` [Pa], held over ``next_state``'s ``dt``;
- **states** the plant's mechanical state (``xf``, ``dxf``, ``xs``, ``xj``, ``dxj``), the valve
  model's own (``p12_warm``: its warm start; for a model with ports ``p1``, ``p2`` and the
  call before's, ``p1_prev``, ``p2_prev``: HD's warm start extrapolates from both), ``p12``
  (the valve's response at the state, with the supply of the last step: an output kept as a
  state, since the valve is algebraic) and one *degradation state* per fault of
  ``degradation`` -- its severity in the catalog's units (:data:`~.physics.faults.FAULTS`),
  held between steps (a slowly varying parameter), moved by its growth rate and by progpy's
  process noise, limited to the catalog's bounds; and one *growth state* per fault,
  ``<fault>_growth`` [severity/s] -- the wear rate, carried as a state the way progpy's own
  wear models carry theirs (PneumaticValve's ``wb``, ``wi``, ...), so that a filter estimates
  it and a prediction extrapolates it; its initial value is the parameter ``growth``;
- **outputs** ``xj``, ``dxj``, ``p12``;
- **events** ``<fault>_alarm``: the degradation reaching its threshold, the parameter
  ``thresholds`` (default the catalog's alarm severity; settable, ``m.parameters['thresholds']
  ['leakage_growth'] = 12.0``); event state 1 when healthy, 0 at the threshold.

Time: the model steps whole control periods. ``simulate_to_threshold`` (and so
``MonteCarlo.predict``) steps at the control period unless given a ``dt`` that is a whole number
of them, and refuses any other ``dt`` (progpy's default, ``('auto', 1.0)``, would check the
events once per second: an event at 0.025 s reported at 1.0 s). Any ``t0`` works (progpy probes
``next_state`` once with ``dt - t0`` to learn its return type; that probe is answered without a
step).

``next_state(x, u, dt)`` advances ``dt`` -- a whole number of control periods -- through the
same compiled tick as the ROS plant (:func:`~.physics.plant.run_tick`): each period the ECU
samples Com and XJ (:func:`~.physics.ecu.ecu_current_py`) and the plant takes the period's DT
steps with Cor, FR and PSR held. With no degradation it is ``simulate(..., ecu_period=
control_period)`` bit for bit (tested); with degradation the parameters are the nominal ones
with each fault at its state's severity (:func:`~.physics.faults.combine`).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from progpy import PrognosticsModel

from .errors import ModelError, ParameterError
from .physics.ecu import ecu_current_py
from .physics.faults import FAULTS, combine
from .physics.params import DEFAULTS, EhaParams, kernel_as_array
from .physics.plant import TICK_OUT, run_tick
from .physics.servovalve import PLANT_STATE, S_SIZE, S_XJ
from .physics.simulate import steps_per, valve_response
from .physics.signals import MEASURED
from .physics.valve_state import V_P1, V_P1_PREV, V_P2, V_P2_PREV, V_P12
from .physics.valves import get_valve_model

#: with ``scaled=True``, each state is carried divided by a power of two near its magnitude on
#: the paper scenario (exact both ways: a scaled run is the unscaled one bit for bit), so that
#: a covariance over states from 1e-5 m to 2e7 Pa stays well conditioned (progpy's
#: UnscentedKalmanFilter factorises one; in SI units its Cholesky fails)
STATE_SCALE = {'xf': 2.0 ** -15, 'dxf': 2.0 ** -6, 'xs': 2.0 ** -13, 'xj': 2.0 ** -5,
               'dxj': 2.0 ** -2, 'p12_warm': 2.0 ** 24, 'p1': 2.0 ** 24, 'p2': 2.0 ** 24,
               'p1_prev': 2.0 ** 24, 'p2_prev': 2.0 ** 24, 'p12': 2.0 ** 24}
#: the valve-state slots a model with ports carries as states
PORT_SLOTS = {'p1': V_P1, 'p2': V_P2, 'p1_prev': V_P1_PREV, 'p2_prev': V_P2_PREV}
#: parameter sets kept per model: a particle filter's particles share few exact severities
#: between resamplings, a deterministic run only one
KERNEL_CACHE = 4096


class EhaModel(PrognosticsModel):
    """The EHA with a valve model of the registry and degradation states (module docstring).

    :param valve_model: a name of :data:`~.physics.valves.VALVE_MODELS` (default SQ)
    :param degradation: catalog faults carried as degradation states
    :param params: the unit's nominal parameters (default :data:`~.physics.params.DEFAULTS`)
    :param control_period: the ECU's sampling period [s], a multiple of DT
    :param scaled: carry the states divided by :data:`STATE_SCALE` (for a Kalman filter)
    :param kwargs: progpy parameters (``process_noise``, ``measurement_noise``, ...) and
        ``growth`` = {fault: initial growth rate, severity per second}, ``x0`` = {fault:
        initial severity}, ``thresholds`` = {fault: severity of its event}
    """

    is_vectorized = True
    inputs = ['com', 'fr', 'psr']
    outputs = list(MEASURED)

    def __init__(self, valve_model: str = 'SQ', degradation: Sequence[str] = ('leakage_growth',),
                 params: EhaParams | None = None, control_period: float = 1e-3,
                 scaled: bool = False, **kwargs: Any):
        unknown = [f for f in degradation if f not in FAULTS]
        if unknown:
            raise ParameterError(f'unknown fault {unknown[0]!r}; expected one of '
                                 f'{sorted(FAULTS)}')
        self.valve = get_valve_model(valve_model)
        self.nominal = params or DEFAULTS
        self.degradation = tuple(degradation)
        self.control_period = float(control_period)
        self.n_sub = steps_per(control_period, self.nominal, 'the control period')
        ports = tuple(PORT_SLOTS) if self.valve.has_ports else ()
        self.states = list(PLANT_STATE) + ['p12_warm', *ports, 'p12', *self.degradation,
                                           *(f'{f}_growth' for f in self.degradation)]
        self.events = [f'{f}_alarm' for f in self.degradation]
        self._limits = [(FAULTS[f].lo, FAULTS[f].hi) for f in self.degradation]
        self._scale = np.array([STATE_SCALE.get(k, 1.0) if scaled else 1.0
                                for k in self.states])[:, None]
        self._i_deg = [self.states.index(f) for f in self.degradation]
        self._i_rate = [self.states.index(f'{f}_growth') for f in self.degradation]
        self._i_ports = [self.states.index(p) for p in ports]
        self._i_p12 = self.states.index('p12')
        self._i_warm = self.states.index('p12_warm')
        self._kernels: dict[tuple[float, ...], tuple[Any, np.ndarray]] = {}
        self._probe = False             # inside simulate_to_threshold, before its first step
        growth = kwargs.pop('growth', {})
        x0 = kwargs.pop('x0', {})
        thresholds = kwargs.pop('thresholds', {})
        for what, d in (('growth', growth), ('x0', x0), ('thresholds', thresholds)):
            extra = set(d) - set(self.degradation)
            if extra:
                raise ParameterError(f'{what} names {sorted(extra)}, which are not degradation '
                                     f'states; expected some of {list(self.degradation)}')
        kwargs.setdefault('process_noise', {k: 0.0 for k in self.states})
        super().__init__(**kwargs)
        self.parameters['growth'] = {f: float(growth.get(f, 0.0)) for f in self.degradation}
        self.parameters['x0'] = {f: float(x0.get(f, FAULTS[f].healthy)) for f in self.degradation}
        self.parameters['thresholds'] = {f: float(thresholds.get(f, FAULTS[f].demo))
                                         for f in self.degradation}
        for f in self.degradation:
            self._threshold(f)

    # -- the physics -----------------------------------------------------------------------
    def _kernel(self, severities: tuple[float, ...]):
        """The compiled physics' parameters with each degradation at its severity."""
        k = self._kernels.get(severities)
        if k is None:
            if len(self._kernels) >= KERNEL_CACHE:
                self._kernels.clear()
            p = combine(self.nominal, dict(zip(self.degradation, severities)))
            kern = self.valve.kernel(p)
            k = self._kernels[severities] = (kern, kernel_as_array(kern))
        return k

    def _threshold(self, fault: str) -> float:
        """The event threshold of ``fault``, checked: beyond the healthy severity on the
        alarm's side (a leak grows, a gain falls), within the catalog's bounds."""
        spec = FAULTS[fault]
        v = self.parameters['thresholds'][fault]
        side = (v - spec.healthy) * (spec.demo - spec.healthy)
        if not (math.isfinite(v) and side > 0 and spec.lo <= v <= spec.hi):
            raise ParameterError(
                f'thresholds[{fault!r}] = {v!r}: expected a severity beyond the healthy '
                f'{spec.healthy:g} towards the alarm {spec.demo:g}, within [{spec.lo:g}, '
                f'{spec.hi:g}]')
        return v

    def _advance(self, col: np.ndarray, com: float, fr: float, psr: float, periods: int,
                 dt: float) -> np.ndarray:
        """One particle's state column ``periods`` control periods on; returns the new one."""
        sev = tuple(min(max(float(col[i]) + float(col[j]) * dt, lo), hi)
                    for i, j, (lo, hi) in zip(self._i_deg, self._i_rate, self._limits))
        kern, arr = self._kernel(sev)
        s = col[:S_SIZE].copy()
        vs = self.valve.initial_state(self.nominal)
        vs[V_P12] = col[self._i_warm]
        for i, slot in zip(self._i_ports, PORT_SLOTS.values()):
            vs[slot] = col[i]
        out = np.empty(len(TICK_OUT))
        for _ in range(periods):
            cor = ecu_current_py(com, float(s[S_XJ]), kern)
            if run_tick(self.valve.id, s, vs, arr, cor, fr, psr, self.n_sub, out) >= 0:
                raise ModelError(f'valve model {self.valve.name} failed to converge')
        new = np.empty_like(col)
        new[:S_SIZE] = s
        self._put_valve(new, vs, arr, fr, psr)
        for i, v in zip(self._i_deg, sev):
            new[i] = v
        new[self._i_rate] = col[self._i_rate]
        return new

    def _put_valve(self, col: np.ndarray, vs: np.ndarray, arr: np.ndarray, fr: float,
                   psr: float) -> None:
        """The valve's own state into ``col``, and P12: its response at ``col``'s plant state
        (on copies, so the run's warm start stays that of its integration steps, as in
        simulate())."""
        col[self._i_warm] = vs[V_P12]
        for i, slot in zip(self._i_ports, PORT_SLOTS.values()):
            col[i] = vs[slot]
        col[self._i_p12] = valve_response(self.valve.id, col[:S_SIZE], vs, arr, fr, psr)[0]

    def _periods(self, dt: float) -> int:
        """``dt`` in control periods. progpy's estimators add their steps up in floating
        point, so a whole number is met to 1e-6 of a period, and what is left of a window
        (1e-17 s) is zero periods: no step."""
        if not self._is_whole(dt):
            raise ParameterError(f'dt = {dt} s must be a whole number of control periods '
                                 f'({self.control_period} s)')
        return int(round(dt / self.control_period))

    # -- progpy's interface ----------------------------------------------------------------
    def initialize(self, u=None, z=None):
        """At rest (the state every run starts from), each degradation at ``x0``; P12 is the
        valve's response at rest to ``u``'s supply (the nominal PSRN without ``u``)."""
        col = np.zeros(len(self.states))
        sev = tuple(self.parameters['x0'][f] for f in self.degradation)
        for i, j, v, f in zip(self._i_deg, self._i_rate, sev, self.degradation):
            col[i] = v
            col[j] = self.parameters['growth'][f]
        psr = float(np.ravel(u['psr'])[0]) if u is not None else self.nominal.PSRN
        self._put_valve(col, self.valve.initial_state(self.nominal), self._kernel(sev)[1], 0.0,
                        psr)
        return self.StateContainer(col.reshape(-1, 1) / self._scale)

    def next_state(self, x, u, dt: float):
        if self._probe:
            # simulate_to_threshold's first call only learns the return type, with dt - t0
            # (negative for t0 > dt): answered without a step, as its result is discarded
            self._probe = False
            if not self._is_whole(dt):
                return self.StateContainer(np.array(x.matrix, dtype=float))
        periods = self._periods(dt)
        if periods == 0:
            return self.StateContainer(np.array(x.matrix, dtype=float))
        com, fr, psr = (float(np.ravel(u[k])[0]) for k in ('com', 'fr', 'psr'))
        X = np.asarray(x.matrix, dtype=float) * self._scale
        new = np.empty_like(X)
        for j in range(X.shape[1]):
            new[:, j] = self._advance(X[:, j], com, fr, psr, periods, dt)
        return self.StateContainer(new / self._scale)

    def simulate_to_threshold(self, future_loading_eqn=None, *args, **kwargs):
        """progpy's, stepping whole control periods: ``dt`` defaults to the control period,
        and one that is not a whole number of them is refused (never a silently coarse or
        misaligned event time)."""
        dt = kwargs.get('dt', self.control_period)
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (
                dt > 0 and self._is_whole(dt)):
            raise ParameterError(
                f'dt = {dt!r}: EhaModel steps whole control periods; give dt as a multiple '
                f'of {self.control_period} s (default: one control period)')
        kwargs['dt'] = float(dt)
        self._probe = True
        try:
            return super().simulate_to_threshold(future_loading_eqn, *args, **kwargs)
        finally:
            self._probe = False

    def _is_whole(self, dt: float) -> bool:
        n = dt / self.control_period
        return math.isfinite(n) and n > -1e-6 and abs(n - round(n)) < 1e-6

    def apply_limits(self, x):
        """Each degradation within the catalog's bounds, and each growth rate on its physical
        side -- toward the alarm (a leak does not heal: a filter whose process noise carried a
        rate below 0 on a model that reads the leak low predicted 'never'), silently: progpy's
        own limits warn at every clip, and a random walk at the healthy bound clips at every
        step."""
        X = x.matrix
        for i, (lo, hi) in zip(self._i_deg, self._limits):
            np.clip(X[i], lo, hi, out=X[i])
        for j, f in zip(self._i_rate, self.degradation):
            if FAULTS[f].demo > FAULTS[f].healthy:
                np.maximum(X[j], 0.0, out=X[j])
            else:
                np.minimum(X[j], 0.0, out=X[j])
        return x

    def output(self, x):
        """XJ, DXJ, P12 in SI units (whether or not the states are scaled)."""
        X = np.asarray(x.matrix, dtype=float) * self._scale
        return self.OutputContainer(X[[self.states.index('xj'), self.states.index('dxj'),
                                       self._i_p12]])

    def _progress(self, x) -> dict[str, np.ndarray]:
        """Each degradation's way from healthy (0) to its threshold (1)."""
        return {f: (np.asarray(x[f], dtype=float) - FAULTS[f].healthy)
                / (self._threshold(f) - FAULTS[f].healthy) for f in self.degradation}

    def event_state(self, x) -> dict:
        return {f'{f}_alarm': np.clip(1.0 - p, 0.0, 1.0) for f, p in self._progress(x).items()}

    def threshold_met(self, x) -> dict:
        return {f'{f}_alarm': p >= 1.0 for f, p in self._progress(x).items()}


__all__ = ['EhaModel']
