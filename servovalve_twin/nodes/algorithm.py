"""The ``algorithm`` node: hosts a user's :class:`~servovalve_twin.prognostics.algorithm.Algorithm`
on the ROS graph -- alone on a timer, or in the twin's lockstep (deterministic, recorded).

Subscribes: the algorithm's ``inputs`` (std_msgs/Float64, the twin's topics).
Publishes: each output on ``<topic_prefix>/<output>`` (std_msgs/Float64; prefix ``algorithm``
unless the class sets another) every control period; ``diagnostics``
(diagnostic_msgs/DiagnosticArray, status ``servovalve_twin: <class>``, its health level,
message and values) every ``diagnostics_period`` and at once when the level changes.
Parameters: ``class`` (``package.module:ClassName``, read-only), the algorithm's own parameters
(typed from their defaults), ``diagnostics_period`` (s), ``control_period`` (s, read-only).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from std_msgs.msg import Float64

from ..errors import TwinError
from ..physics.params import DEFAULTS, EhaParams
from ..prognostics.algorithm import (Algorithm, AlgorithmError, AlgorithmRunner, Health,
                                     load_algorithm)
from .base import TwinNode
from .process import spin_standalone

_DEFAULT_INPUT = {'psr': DEFAULTS.PSRN}


def algorithm_topics(alg: Algorithm) -> dict[str, tuple]:
    """The topics an algorithm node publishes, in the table form of :data:`common.TOPICS`."""
    out = {f'{alg.topic_prefix}/{name}': (Float64, 'SI', alg.title, f'output {name}')
           for name in alg.outputs}
    out['diagnostics'] = (DiagnosticArray, '-', alg.title, 'health, level OK/WARN/ERROR')
    return out


#: the range of ``diagnostics_period`` [s]: a number of nanoseconds the node can hold (an
#: infinite one killed the node in its next tick: OverflowError converting it to ns)
MIN_DIAGNOSTICS_PERIOD, MAX_DIAGNOSTICS_PERIOD = 1e-6, 1e6


def _check_period(period: Any) -> None:
    if not (isinstance(period, (int, float)) and not isinstance(period, bool)
            and MIN_DIAGNOSTICS_PERIOD <= period <= MAX_DIAGNOSTICS_PERIOD):
        raise TwinError(f'diagnostics_period must be a number of seconds in '
                        f'[{MIN_DIAGNOSTICS_PERIOD:g}, {MAX_DIAGNOSTICS_PERIOD:g}], got '
                        f'{period!r}')


class AlgorithmNode(TwinNode):
    """Hosts ``algorithm`` (an instance; alone, built from the ``class`` parameter)."""

    def __init__(self, algorithm: Algorithm | None = None, *, name: str = 'algorithm',
                 **kwargs):
        super().__init__(name, **kwargs)
        self.declare_parameter('class', '' if algorithm is None else (
            f'{type(algorithm).__module__}:{type(algorithm).__qualname__}'),
            ParameterDescriptor(description='the algorithm, package.module:ClassName',
                                read_only=True))
        self.declare_parameter('diagnostics_period', 0.01, ParameterDescriptor(
            description='DiagnosticArray period [s] (and at every level change)',
            floating_point_range=[FloatingPointRange(
                from_value=MIN_DIAGNOSTICS_PERIOD, to_value=MAX_DIAGNOSTICS_PERIOD,
                step=0.0)]))
        _check_period(self.get_parameter('diagnostics_period').value)
        if algorithm is None:
            spec = self.get_parameter('class').value
            if not spec:
                raise AlgorithmError('give the algorithm: --ros-args -p '
                                     'class:=package.module:ClassName')
            cls_params = self._declared_algorithm_params(load_algorithm(spec))
            algorithm = load_algorithm(spec, cls_params)
        else:
            self._declared_algorithm_params(algorithm)
        self.alg = algorithm
        self.runner = AlgorithmRunner(algorithm, self.period, self.nominal_params())
        self.level = 0
        self._last_diag_ns: int | None = None
        self.error: str | None = None
        self._dropped = 0                          # implausible samples the algorithm dropped
        self.first_level: dict[int, float] = {}    # level -> first time [s] it was reached
        self.peaks: dict[str, float] = {}          # output -> largest value
        table = algorithm_topics(algorithm)
        self.add_publishers(table, table)
        self.start_inputs({s: _DEFAULT_INPUT.get(s, 0.0) for s in algorithm.inputs})
        self.start()

    def nominal_params(self) -> EhaParams:
        return self.params

    def _declared_algorithm_params(self, alg: Algorithm) -> dict[str, Any]:
        """Declare the algorithm's parameters (typed from its current values) and return the
        values given with ``-p``."""
        values = {}
        for pname, value in alg.params.items():
            self.declare_parameter(pname, value, ParameterDescriptor(
                description=f'parameter of {alg.title}', read_only=True))
            values[pname] = self.get_parameter(pname).value
        return values

    def check_parameters(self, changes: dict[str, Any]) -> None:
        if 'diagnostics_period' in changes:
            _check_period(changes['diagnostics_period'])
        super().check_parameters(changes)

    def step(self, tick: tuple[int, int], values: dict[str, float]) -> None:
        self._advance(tick[0], values)

    def on_timer(self) -> None:
        if self.error is not None:
            return
        try:
            self._advance(self.get_clock().now().nanoseconds, dict(self.io.latest))
        except AlgorithmError as exc:
            self.error = str(exc)
            self.get_logger().error(f'{exc}; the algorithm is stopped')

    def _advance(self, t_ns: int, u: dict[str, float]) -> None:
        outputs, health = self.runner.step(t_ns, u)
        dropped = getattr(self.alg, 'dropped', 0)
        if dropped != self._dropped:
            # an algorithm that drops implausible samples (the monitor) goes on: said at most
            # once a second
            self._dropped = dropped
            self.get_logger().warning(f'{dropped} implausible samples dropped (last: '
                                      f'{getattr(self.alg, "last_dropped", "")})',
                                      throttle_duration_sec=1.0)
        prefix = self.alg.topic_prefix
        for name, v in outputs.items():
            self.emit_value(f'{prefix}/{name}', v)
            if not v <= self.peaks.get(name, -math.inf):
                self.peaks[name] = v
        if health is None:
            return
        for level in range(1, health.level + 1):
            self.first_level.setdefault(level, t_ns * 1e-9)
        period_ns = int(round(self.get_parameter('diagnostics_period').value * 1e9))
        if (health.level != self.level or self._last_diag_ns is None
                or t_ns - self._last_diag_ns >= period_ns):
            self._publish_diagnostics(t_ns, health)
        self.level = health.level

    def _publish_diagnostics(self, t_ns: int, health: Health) -> None:
        self._last_diag_ns = t_ns
        msg = DiagnosticArray()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
        st = DiagnosticStatus()
        st.level = bytes([health.level])
        st.name = f'servovalve_twin: {self.alg.title}'
        st.hardware_id = 'eha'
        st.message = health.message
        st.values = [KeyValue(key=k, value=repr(float(v)) if isinstance(v, float) else str(v))
                     for k, v in health.values.items()]
        msg.status = [st]
        self.emit('diagnostics', msg)


def main(args: Sequence[str] | None = None) -> int:
    return spin_standalone(AlgorithmNode, args)


__all__ = ['AlgorithmNode', 'algorithm_topics', 'main']


def verdict(node: AlgorithmNode) -> str:
    """One line: the first WARN and ERROR times and the peak outputs of a hosted algorithm."""
    first = node.first_level
    when = ', '.join(f'first {n} at {first[lv]:.3f} s' if lv in first else f'no {n}'
                     for lv, n in ((1, 'WARN'), (2, 'ERROR')))
    peaks = ', '.join(f'{k} {v:.4g}' for k, v in node.peaks.items() if 'residual' not in k)
    return f'{node.alg.title}: {when}; peak {peaks}'
