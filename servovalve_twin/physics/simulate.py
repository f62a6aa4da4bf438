"""ROS-free runs: :func:`simulate` (a whole scenario in one compiled call) and :class:`EhaPlant`
(the stateful plant the ROS node advances one control period at a time). Both go through
:func:`~.plant.plant_step` (:func:`~.plant.run_steps_for` and :func:`~.plant.run_tick`).

Run conventions (doc/design/MODELS.md section 9): time is an integer count of DT steps; inputs
are held
over a step; output row i holds t_i = i*1 ms, the state at t_i, and the inputs, Cor and P12 in
force on the step that starts at t_i. Scenarios come in as :class:`~.scenario.Scenario` objects
or mappings: reading files (built-in names, YAML) is :mod:`servovalve_twin.config`'s, and
:func:`servovalve_twin.runs.simulate` takes a name or a path.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import numpy as np

from ..errors import ModelError, ParameterError
from .ecu import ecu_current_py
from .faults import params_after as fault_params
from .params import DEFAULTS, EhaParams, stack_kernels
from .plant import OUT_COLUMNS, TICK_OUT, TRUTH_COLUMNS, run_steps_for, tick_for
from .scenario import GridBuffers, Scenario, as_scenario
from .sensors import N_STATE, SENSED, Sensors, sense_block, sensor_table, sensors_from_dict
from .servovalve import PLANT_STATE, S_DXJ, S_SIZE, S_XJ, S_XS
from .signals import COMMON, PORTS
from .valves import ValveModel, get_valve_model

OUTPUT_PERIOD_NS = 1_000_000     # output rows every 1 ms
#: steps per chunk: simulate() evaluates the inputs and runs the compiled loop chunk by chunk,
#: so its memory is that of the output rows plus a few chunks' inputs (the scenario keeps its
#: last four per signal: ~6 MB, :data:`~.scenario.GRID_CACHE`), whatever the run's length;
#: 2**16 rather than 2**14 steps: fewer chunk entries (numpy calls, the loop call) per run;
#: 2**17 measured no faster here (bench_physics, interleaved)
CHUNK_STEPS = 1 << 16
CSV_COLUMNS = ('t',) + COMMON
PORT_COLUMNS = PORTS
SIGNAL_UNITS = dict(t='s', com='m', fr='N', psr='Pa', cor='A', xs='m', xj='m', dxj='m/s',
                    p12='Pa', qj='m^3/s', p1='Pa', p2='Pa')


def effective_params(scenario: Scenario, overrides: Mapping[str, Any] | None = None,
                     base: EhaParams | None = None) -> EhaParams:
    """Defaults, then the scenario's ``params``, then the user's overrides (later wins)."""
    p = base or DEFAULTS
    for changes in (scenario.params, overrides):
        if changes:                     # each replace() re-validates every field (~0.2 ms)
            p = p.replace(**dict(changes))
    return p


#: the longest ECU or control period [s]: 10 Hz, far below any flight-control loop; beyond it
#: the loop barely samples (an ECU every 1e9 s never sampled after t = 0: a run without control)
MAX_PERIOD = 0.1


def steps_per(period_s: float, params: EhaParams, what: str) -> int:
    """How many DT steps make ``period_s``; it must be a whole number of them, at most
    :data:`MAX_PERIOD`."""
    if not (isinstance(period_s, (int, float)) and math.isfinite(period_s) and period_s > 0):
        raise ParameterError(f'{what} must be a positive number of seconds, got {period_s!r}')
    if period_s > MAX_PERIOD:
        raise ParameterError(f'{what} = {period_s:g} s is longer than {MAX_PERIOD:g} s (a loop '
                             f'sampled below {1 / MAX_PERIOD:g} Hz does not control the actuator)')
    period_ns = int(round(period_s * 1e9))
    if period_ns < params.dt_ns:
        raise ParameterError(f'{what} = {period_s} s is shorter than DT = {params.DT} s')
    if abs(period_s * 1e9 - period_ns) > 1e-6 or period_ns % params.dt_ns:
        raise ParameterError(f'{what} = {period_s} s must be a whole multiple of DT = '
                             f'{params.DT} s')
    return period_ns // params.dt_ns


@dataclasses.dataclass
class RunResult:
    """A run's labelled signals (1 ms rows, SI units) and its provenance and diagnostics."""

    valve_model: str
    scenario: Scenario
    params: EhaParams
    signals: dict[str, np.ndarray]
    ecu_period: float | None = None
    info: dict[str, Any] = dataclasses.field(default_factory=dict)
    #: the sensors the run was measured with (None: ideal), and the true values of the
    #: signals they read (``signals`` holds the readings)
    sensors: Sensors | None = None
    truth: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    @property
    def columns(self) -> tuple[str, ...]:
        return tuple(self.signals)

    def window(self, t0: float, t1: float, closed: bool = False) -> np.ndarray:
        """Boolean mask of the rows with t0 <= t < t1 (<= t1 when ``closed``), in whole ms."""
        ms = np.rint(self.signals['t'] * 1000).astype(np.int64)
        a, b = int(round(t0 * 1000)), int(round(t1 * 1000))
        return (ms >= a) & ((ms <= b) if closed else (ms < b))


def simulate(valve_model: str, scenario: Scenario | Mapping,
             overrides: Mapping[str, Any] | None = None, *, ecu_period: float | None = None,
             params: EhaParams | None = None,
             initial: Mapping[str, float] | None = None,
             sensors: Sensors | Mapping | None = None,
             sensor_seed: int | None = None) -> RunResult:
    """Run ``scenario`` with ``valve_model``, ROS-free, in one compiled loop.

    :param valve_model: a name of :data:`~.valves.VALVE_MODELS`
    :param scenario: a :class:`Scenario` or a mapping of the scenario schema
    :param overrides: parameter name -> value, applied after the scenario's own ``params``
    :param ecu_period: sample the ECU with this period [s] (a multiple of DT); None = continuous
    :param params: base parameters (default :data:`~.params.DEFAULTS`)
    :param initial: the plant state at t = 0 by name (:data:`~.servovalve.PLANT_STATE`:
        ``xf``, ``dxf``, ``xs``, ``xj``, ``dxj``; the others at rest): a run that continues
        from a recorded instant (a diagnosis over a window); the valve state starts afresh
    :param sensors: the sensors (:mod:`.sensors`; a mapping of the scenario's ``sensors``
        schema) instead of the scenario's; ``sensor_seed``: their seed instead of theirs.
        With sensors the ECU closes its loop on the measured XJ, ``signals`` holds what the
        sensors read and ``truth`` the true values of the sensed signals.
    :raises TwinError: bad model name, parameter, scenario, period; valve failure
    """
    model = get_valve_model(valve_model)
    scn = as_scenario(scenario)
    p = effective_params(scn, overrides, params)
    out_every = steps_per(OUTPUT_PERIOD_NS * 1e-9, p, 'the 1 ms output period')
    ecu_every = 0 if ecu_period is None else steps_per(ecu_period, p, 'the ECU period')
    n_steps = scn.duration_ns // p.dt_ns
    if n_steps * p.dt_ns != scn.duration_ns:
        raise ParameterError(f'duration {scn.duration} s is not a whole number of DT = {p.DT} s')
    n_rows = n_steps // out_every + 1      # the memory: ~0.2 kB per row, 0.7 GB at 3600 s
    kernels, seg_start = _fault_segments(model, scn, p)
    # the scenario carries the sensors that measured the run (the result says so)
    if sensors is not None:
        scn = dataclasses.replace(scn, sensors=sensors if isinstance(sensors, Sensors)
                                  else sensors_from_dict(sensors))
    if sensor_seed is not None:
        scn = scn.with_sensor_seed(sensor_seed)
    sens = scn.sensors
    # a sensor samples every control period by default: the ECU's, or the output rows' when
    # the ECU is continuous (its readings are held between them)
    spec, keys = sensor_table(sens, ecu_every or out_every, p.DT)
    held = np.zeros(len(SENSED))
    out = np.full((n_rows, len(OUT_COLUMNS) + (len(TRUTH_COLUMNS) if sens else 0)), np.nan)
    s = np.zeros(S_SIZE)
    for name, value in (initial or {}).items():
        if name not in PLANT_STATE:
            raise ParameterError(f'initial: unknown plant state {name!r}; expected some of '
                                 f'{list(PLANT_STATE)}')
        if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)):
            raise ParameterError(f'initial {name} must be a finite number, got {value!r}')
        s[PLANT_STATE.index(name)] = float(value)
    vs = model.initial_state(p)
    carry = np.zeros(2)             # Cor and the parameter segment, carried between chunks
    run_steps = run_steps_for(model.id, bool(sens))
    buffers = GridBuffers.reused(min(CHUNK_STEPS, n_steps + 1))
    for i0 in range(0, n_steps + 1, CHUNK_STEPS):
        m = min(CHUNK_STEPS, n_steps + 1 - i0)
        # the chunk's inputs, kept by the scenario when it is run again (a fit's hundreds)
        com, fr, psr = scn.grid_inputs(i0 * p.dt_ns, p.dt_ns, m, buffers)
        failed = run_steps(s, vs, kernels, seg_start, com, fr, psr, i0, n_steps,
                           ecu_every, out_every, carry, out, OUTPUT_PERIOD_NS * 1e-9,
                           spec, keys, held, ecu_every or out_every)
        if failed >= 0:
            raise ModelError(f'valve model {model.name} failed to converge at t = '
                             f'{failed * p.DT:.6f} s')
    cols = CSV_COLUMNS + (PORT_COLUMNS if model.has_ports else ())
    signals = {c: out[:, OUT_COLUMNS.index(c)].copy() for c in cols}
    truth = {}
    if sens:
        truth = {c: out[:, len(OUT_COLUMNS) + SENSED.index(c)].copy() for c in sens.names
                 if c in cols}
    return RunResult(valve_model=model.name, scenario=scn, params=p, signals=signals,
                     ecu_period=ecu_period, info=dict(model.run_totals(vs), steps=n_steps),
                     sensors=sens or None, truth=truth)


def _fault_segments(model: ValveModel, scn: Scenario, p: EhaParams
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Stacked kernel parameters, one row per stretch between fault events, and the first
    step of each (an event applies from the first step starting at or after it)."""
    events = scn.fault_events(p)
    times = sorted({int(round(e.at * 1e9)) for e in events})
    rows = [model.kernel_array(p)] + [model.kernel_array(fault_params(events, p, t * 1e-9))
                                      for t in times]
    start = [0] + [-(-t // p.dt_ns) for t in times]
    return stack_kernels(rows), np.array(start, dtype=np.int64)


def valve_response(model_id: int, s: np.ndarray, vs: np.ndarray, kernel_arr: np.ndarray,
                   fr: float, psr: float) -> np.ndarray:
    """P12, QJ, P1, P2 of the valve at the plant state ``s`` for supply ``psr``, evaluated on
    copies of the states: the run continues as if it had not been asked (a valve's warm start
    and counters stay those of its integration steps)."""
    out = np.full(len(TICK_OUT), np.nan)
    tick_for(model_id)(model_id, s.copy(), vs.copy(), kernel_arr, 0.0, float(fr), float(psr), 0,
                       out)
    return out


class EhaPlant:
    """The plant as an object advanced one control period at a time (the ROS plant's physics).

    It owns the mechanical state (XF, DXF, XS, XJ, DXJ) and the valve state; switching the valve
    model keeps the mechanical state and gives the new model a fresh valve state whose warm
    start is the last P12 and port pressures.
    """

    def __init__(self, valve_model: str = 'C2', params: EhaParams | None = None):
        self.params = params or DEFAULTS
        self.model = get_valve_model(valve_model)
        self._kernel = self.model.kernel(self.params)
        self._kernel_arr = self.model.kernel_array(self.params)
        self._tick = tick_for(self.model.id)
        self.s = np.zeros(S_SIZE)
        self.vs = self.model.initial_state(self.params)
        self.last = np.full(len(TICK_OUT), np.nan)
        self.sensors: Sensors | None = None
        self.measured = np.zeros(len(SENSED))     # the sensors' readings, :data:`SENSED` order
        self._spec, self._keys = sensor_table(None, 1, self.params.DT)
        self.compile()

    def set_sensors(self, sensors: Sensors | None, control_period: float) -> None:
        """Measure with ``sensors`` (None: ideal), sampled on the grid of ``control_period``
        (s): the readings of :meth:`sense_state` and :meth:`sense_valve` are those
        :func:`simulate` takes with ``ecu_period`` = ``control_period``."""
        self.sensors = sensors or None
        self._spec, self._keys = sensor_table(
            sensors, steps_per(control_period, self.params, 'the control period'),
            self.params.DT)

    def sense_state(self, t_ns: int) -> np.ndarray:
        """Read XS, XJ, DXJ at ``t_ns`` (the start of a control period) into
        :attr:`measured`; returns the readings of the state signals."""
        sense_block(0, self.s[[S_XS, S_XJ, S_DXJ]], t_ns // self.params.dt_ns, self._spec,
                    self._keys, self.measured)
        return self.measured[:N_STATE]

    def sense_valve(self, t_ns: int) -> np.ndarray:
        """Read P12, P1, P2 of :attr:`last` (the valve at ``t_ns``, the tick's start)."""
        sense_block(N_STATE, self.last[[0, 2, 3]], t_ns // self.params.dt_ns, self._spec,
                    self._keys, self.measured)
        return self.measured[N_STATE:]

    @property
    def xs(self) -> float:
        return float(self.s[S_XS])

    @property
    def xj(self) -> float:
        return float(self.s[S_XJ])

    @property
    def dxj(self) -> float:
        return float(self.s[S_DXJ])

    def set_valve_model(self, name: str) -> None:
        """Continue with another fluid model; mechanical state kept, warm starts carried."""
        new = get_valve_model(name)
        if new is self.model:
            return
        self.vs = new.take_over(self.params, self.model, self.vs, self.xj)
        self.model = new
        self._kernel = new.kernel(self.params)
        self._kernel_arr = new.kernel_array(self.params)
        self._tick = tick_for(new.id)
        self.compile()

    def set_params(self, params: EhaParams) -> None:
        """Continue with new parameters (a fault, a retune); the state is kept."""
        self.params = params
        self._kernel = self.model.kernel(params)
        self._kernel_arr = self.model.kernel_array(params)

    def control(self, com: float, xj: float) -> float:
        """The ECU law: the source of the compiled function :func:`simulate` uses, evaluated
        by the interpreter (a compiled call costs more to enter than this law costs to compute;
        IEEE arithmetic makes both bit-identical, which the tests check)."""
        return float(ecu_current_py(float(com), float(xj), self._kernel))

    def tick(self, cor: float, fr: float, psr: float, n_sub: int) -> np.ndarray:
        """Advance ``n_sub`` steps with Cor, FR, PSR held; returns P12, QJ, P1, P2 at the tick's
        start (``n_sub`` = 0: evaluate only)."""
        if not (math.isfinite(cor) and math.isfinite(fr) and math.isfinite(psr)):
            for label, v in (('Cor', cor), ('FR', fr), ('PSR', psr)):
                if not math.isfinite(v):
                    raise ModelError(f'{label} must be finite, got {v!r}')
        failed = self._tick(self.model.id, self.s, self.vs, self._kernel_arr, float(cor),
                            float(fr), float(psr), int(n_sub), self.last)
        if failed >= 0:
            raise ModelError(f'valve model {self.model.name} failed to converge')
        return self.last        # P1, P2: NaN for a model without ports (its state holds NaN)

    def response(self, fr: float, psr: float) -> np.ndarray:
        """P12, QJ, P1, P2 at the current state for supply ``psr`` (:func:`valve_response`)."""
        return valve_response(self.model.id, self.s, self.vs, self._kernel_arr, fr, psr)

    def compile(self) -> None:
        """Load the tick loop of the current model now -- the compiled module's, or, without
        it, the JIT's, compiled (seconds) -- by a tick on scratch copies of the state: run when
        the plant is built and when it changes model, so that a node built on it says it has
        started once it can tick, the first real tick costs what every tick costs, and a Ctrl-C
        is not held up by a compile."""
        self._tick(self.model.id, self.s.copy(), self.vs.copy(), self._kernel_arr, 0.0, 0.0,
                 self.params.PSRN, 1, np.zeros(len(TICK_OUT)))


__all__ = ['simulate', 'RunResult', 'EhaPlant', 'valve_response', 'effective_params',
           'CSV_COLUMNS', 'PORT_COLUMNS', 'SIGNAL_UNITS']
