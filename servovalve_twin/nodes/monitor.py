"""The monitor node: the built-in residual monitor
(:class:`~servovalve_twin.prognostics.monitor.MonitorAlgorithm`) hosted like any algorithm.

It runs its own copy of the actuator -- ECU law, servovalve, the chosen simplified valve model
(default SQ: :data:`~..prognostics.monitor.DEFAULT_MONITOR_MODEL`), jack -- with the
*nominal* parameters, on the same Com, FR and PSR as the plant, and compares it with what the
plant publishes.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor

from ..physics.params import PARAM_NAMES, EhaParams
from ..physics.valves import MONITOR_MODEL_NAMES, get_monitor_model
from ..prognostics.monitor import DEFAULT_MONITOR_MODEL, HealthConfig, MonitorAlgorithm
from .algorithm import AlgorithmNode, algorithm_topics
from .process import spin_standalone

INPUTS = MonitorAlgorithm.inputs
HEALTH_FIELDS = tuple(f.name for f in dataclasses.fields(HealthConfig))
_HEALTH_DOC = {'window': 'moving-RMS window [s]'}
#: the monitor's topics (``monitor/residual_*``, ``monitor/health_*``, ``diagnostics``)
MONITOR_TOPICS = algorithm_topics(MonitorAlgorithm())


class Monitor(AlgorithmNode):
    """Monitor model beside the plant.

    Subscribes: ``com``, ``fr``, ``psr`` (the plant's inputs), ``xj``, ``dxj``, ``p12`` (the
    plant's outputs), all std_msgs/Float64.
    Publishes: ``monitor/residual_{xj,dxj,p12}`` and ``monitor/health_{xj,dxj,p12}``
    (std_msgs/Float64, m, m/s, Pa: residual plant - model, and its moving RMS) every control
    period; ``diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period`` and
    at once when the level changes.
    Parameters: ``monitor_model`` (string, a model the registry allows as monitor; default SQ),
    ``window`` and ``warn_*``/``error_*`` thresholds (double, SI; defaults from the model's
    calibrated thresholds), ``diagnostics_period`` (s), ``control_period`` (s, read-only) and the
    nominal physical parameters of the whole actuator it models (ECU and plant).
    """

    @classmethod
    def declared_physical(cls) -> tuple[str, ...]:
        """All of them: the monitor models the whole actuator, ECU included."""
        return PARAM_NAMES

    def __init__(self, **kwargs):
        # the monitor's own parameters are declared by this node (switchable at run time),
        # not as the algorithm's read-only ones (_declared_algorithm_params below)
        super().__init__(MonitorAlgorithm(), name='monitor', **kwargs)

    def _declared_algorithm_params(self, alg) -> dict[str, Any]:
        self.declare_parameter('monitor_model', DEFAULT_MONITOR_MODEL, ParameterDescriptor(
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
        if model != alg.params['monitor_model']:
            alg.__init__(monitor_model=model)
        alg.config = self._config()
        return {}

    def _config(self) -> HealthConfig:
        return HealthConfig(**{f: self.get_parameter(f).value for f in HEALTH_FIELDS})

    @property
    def model(self):
        """The monitor model's plant (physics.simulate.EhaPlant)."""
        return self.alg.plant

    def check_parameters(self, changes: dict[str, Any]) -> None:
        if 'monitor_model' in changes:
            get_monitor_model(changes['monitor_model'])
        if any(f in changes for f in HEALTH_FIELDS):
            HealthConfig(**{f: float(changes.get(f, self.get_parameter(f).value))
                            for f in HEALTH_FIELDS})          # thresholds ordered, window > 0
        super().check_parameters(changes)

    def on_params(self, params: EhaParams) -> None:
        self.alg.set_nominal(params)

    def apply_parameters(self, changes: dict[str, Any]) -> None:
        if 'monitor_model' in changes:
            self.alg.set_monitor_model(changes['monitor_model'])
        super().apply_parameters(changes)
        self.alg.set_config(self._config())


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(Monitor, args)
