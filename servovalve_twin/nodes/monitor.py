"""The monitor node: a simplified EHA model beside the plant, residuals and a health level.

It runs its own copy of the actuator -- ECU law, servovalve, the chosen simplified valve model
(default C2), jack -- with the *nominal* parameters, on the same Com, FR and PSR as the plant,
and compares it with what the plant publishes (:mod:`servovalve_twin.prognostics.monitor`).
"""

from __future__ import annotations

from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from std_msgs.msg import Float64

from ..physics.params import PARAM_NAMES, EhaParams
from ..physics.simulate import EhaPlant, steps_per
from ..physics.valves import MONITOR_MODEL_NAMES, get_monitor_model
from ..prognostics.monitor import LEVEL_NAMES, RESIDUALS, HealthConfig, HealthFilter
from .common import TwinNode, spin_standalone

INPUTS = ('com', 'fr', 'psr', 'xj', 'dxj', 'p12')
MONITOR_TOPICS = {
    **{f'monitor/residual_{s}': (Float64, unit, 'monitor', f'plant - monitor model, {s.upper()}')
       for s, unit in (('xj', 'm'), ('dxj', 'm/s'), ('p12', 'Pa'))},
    **{f'monitor/health_{s}': (Float64, unit, 'monitor',
                               f'moving RMS of the {s.upper()} residual')
       for s, unit in (('xj', 'm'), ('dxj', 'm/s'), ('p12', 'Pa'))},
    'diagnostics': (DiagnosticArray, '-', 'monitor',
                    "status 'servovalve_twin: EHA monitor', level OK/WARN/ERROR, residuals"),
}
_HEALTH_DOC = {'window': 'moving-RMS window [s]'}
HEALTH_FIELDS = ('window', 'warn_xj', 'error_xj', 'warn_dxj', 'error_dxj', 'warn_p12',
                 'error_p12')


class Monitor(TwinNode):
    """Monitor model beside the plant.

    Subscribes: ``com``, ``fr``, ``psr`` (the plant's inputs), ``xj``, ``dxj``, ``p12`` (the
    plant's outputs), all std_msgs/Float64.
    Publishes: ``monitor/residual_{xj,dxj,p12}`` and ``monitor/health_{xj,dxj,p12}``
    (std_msgs/Float64, m, m/s, Pa: residual plant - model, and its moving RMS) every control
    period; ``diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period`` and
    at once when the level changes.
    Parameters: ``monitor_model`` (string, a model the registry allows as monitor; default C2),
    ``window`` and ``warn_*``/``error_*`` thresholds (double, SI; defaults from the model's
    registry entry), ``diagnostics_period`` (s), ``control_period`` (s, read-only) and the
    nominal physical parameters of the whole actuator it models (ECU and plant).
    """

    @classmethod
    def declared_physical(cls) -> tuple[str, ...]:
        """All of them: the monitor models the whole actuator, ECU included."""
        return PARAM_NAMES

    def __init__(self, **kwargs):
        super().__init__('monitor', **kwargs)
        self.declare_parameter('monitor_model', 'C2', ParameterDescriptor(
            description='simplified valve model of the monitor',
            additional_constraints='one of: ' + ', '.join(MONITOR_MODEL_NAMES)))
        model = self.get_parameter('monitor_model').value
        get_monitor_model(model)
        defaults = HealthConfig.for_model(model)
        for field in HEALTH_FIELDS:
            self.declare_parameter(field, float(getattr(defaults, field)), ParameterDescriptor(
                description=_HEALTH_DOC.get(field, f'{field.replace("_", " ")} threshold of '
                                            'the residual moving RMS [SI]'),
                floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1e9,
                                                         step=0.0)]))
        self.declare_parameter('diagnostics_period', 0.01, ParameterDescriptor(
            description='DiagnosticArray period [s] (and at every level change)'))
        self.model = EhaPlant(model, self.params)
        self.n_sub = steps_per(self.period, self.params, 'control_period')
        self.filter = HealthFilter(self._config(), self.period)
        self.level = 0
        self._last_diag_ns: int | None = None
        self.add_publishers(MONITOR_TOPICS, MONITOR_TOPICS)
        defaults = {k: 0.0 for k in INPUTS}
        defaults['psr'] = self.params.PSRN
        self.start_inputs(defaults)
        self.start()

    def _config(self) -> HealthConfig:
        return HealthConfig(**{f: self.get_parameter(f).value for f in HEALTH_FIELDS})

    def check_parameters(self, changes: dict[str, Any]) -> None:
        if 'monitor_model' in changes:
            get_monitor_model(changes['monitor_model'])
        if any(f in changes for f in HEALTH_FIELDS):
            HealthConfig(**{f: float(changes.get(f, self.get_parameter(f).value))
                            for f in HEALTH_FIELDS})          # thresholds ordered, window > 0
        super().check_parameters(changes)

    def on_params(self, params: EhaParams) -> None:
        self.model.set_params(params)

    def apply_parameters(self, changes: dict[str, Any]) -> None:
        if 'monitor_model' in changes:
            self.model.set_valve_model(changes['monitor_model'])
        super().apply_parameters(changes)
        self.filter = HealthFilter(self._config(), self.period)

    def step(self, tick: tuple[int, int], values: dict[str, float]) -> None:
        t_ns, n_sub = tick
        self._advance(t_ns, n_sub, values)

    def _advance(self, t_ns: int, n_sub: int, v: dict[str, float]) -> None:
        # the monitor's own loop: its ECU sees its own XJ, as the real ECU sees the plant's
        xj_m, dxj_m = self.model.xj, self.model.dxj
        cor = self.model.control(v['com'], xj_m)
        p12_m = float(self.model.tick(cor, v['fr'], v['psr'], n_sub)[0])
        residual = {'xj': v['xj'] - xj_m, 'dxj': v['dxj'] - dxj_m, 'p12': v['p12'] - p12_m}
        level, health = self.filter.update(residual)
        for s in RESIDUALS:
            self.emit_value(f'monitor/residual_{s}', residual[s])
            self.emit_value(f'monitor/health_{s}', health[s])
        period_ns = int(round(self.get_parameter('diagnostics_period').value * 1e9))
        if (level != self.level or self._last_diag_ns is None
                or t_ns - self._last_diag_ns >= period_ns):
            self._publish_diagnostics(t_ns, level, residual, health)
        self.level = level

    def _publish_diagnostics(self, t_ns: int, level: int, residual, health) -> None:
        self._last_diag_ns = t_ns
        msg = DiagnosticArray()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
        st = DiagnosticStatus()
        st.level = bytes([level])
        st.name = 'servovalve_twin: EHA monitor'
        st.hardware_id = 'eha'
        worst = max(RESIDUALS, key=lambda s: health[s] / self.filter.config.thresholds(s)[1])
        unit = {'xj': 'm', 'dxj': 'm/s', 'p12': 'Pa'}[worst]
        st.message = (f'{LEVEL_NAMES[level]}: largest residual {worst.upper()} '
                      f'(moving RMS {health[worst]:.4g} {unit}, relative to its ERROR '
                      f'threshold) against model {self.model.model.name}')
        st.values = [KeyValue(key=f'residual_{s}', value=repr(residual[s])) for s in RESIDUALS]
        st.values += [KeyValue(key=f'health_{s}', value=repr(health[s])) for s in RESIDUALS]
        msg.status = [st]
        self.emit('diagnostics', msg)

    def on_timer(self) -> None:
        self._advance(self.get_clock().now().nanoseconds, self.n_sub, dict(self.io.latest))


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Monitor, args)
