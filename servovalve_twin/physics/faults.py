"""Fault injection: degradations of the EHA as parameter changes, named, documented, bounded.

Each fault maps a *severity* to a parameter value computed from the nominal (fault-free)
parameters, so that a severity means the same whatever else was changed. Faults enter a run
as time-scheduled events of a scenario (``faults:``) or, on the ROS plant, as parameter sets at
run time (``ros2 param set /plant CLk 2.0e-12``).

Scenario schema::

    faults:
      - {at: 0.5, fault: leakage_growth, severity: 10.0}   # a named fault
      - {at: 0.8, param: CorB, value: 0.0005}              # any parameter, set directly
"""

from __future__ import annotations

import math

import dataclasses
from typing import Any, Mapping, Sequence

from ..errors import ScenarioError, TwinError
from .params import EhaParams


@dataclasses.dataclass(frozen=True)
class FaultSpec:
    """A named degradation: which parameter, how severity maps to it, its physical meaning."""

    name: str
    param: str
    kind: str              # 'scale': param = nominal*severity; 'loss': nominal*(1 - severity);
    #                        'value': param = severity
    lo: float
    hi: float
    unit: str
    meaning: str
    demo: float            # the documented severity at which the monitor must raise an alarm

    @property
    def healthy(self) -> float:
        """The severity that leaves the unit as it is: 1 for a multiplier, 0 otherwise."""
        return 1.0 if self.kind == 'scale' else 0.0

    def to_g(self, s: float) -> float:
        """A severity in the fault's own coordinate ``g``: the logarithm of a multiplier
        (healthy 1 -> 0), a fraction or a value as a share of the way from healthy to the alarm
        value -- the coordinate in which diagnosis calibrates and states sizes (a leak's error
        grows with its size; a loss's does not)."""
        if self.kind == 'scale':
            return math.log(max(s, 1e-12) / self.healthy)
        return (s - self.healthy) / abs(self.demo - self.healthy)

    def from_g(self, g: float) -> float:
        """The severity at ``g`` (the inverse of :meth:`to_g`)."""
        if self.kind == 'scale':
            return self.healthy * math.exp(g)
        return self.healthy + g * abs(self.demo - self.healthy)

    def show(self, s: float, unit: bool = True) -> str:
        """A severity as a reader wants it: 4 significant digits with its unit (a null bias in
        mA): '6.012 x CLk', '0.2817 of PSR', '-1.214 mA'; ``unit`` False: the number alone, in
        that unit."""
        if self.unit == 'A':
            return f'{s * 1e3:.4g}' + (' mA' if unit else '')
        return f'{s:.4g}' + (f' {self.unit.replace("fraction ", "")}' if unit else '')

    def severity_of(self, nominal: EhaParams, value: float) -> float:
        """The inverse of :meth:`value`: the severity at which the parameter is ``value``,
        read against ``nominal`` (no bounds checked: a unit's own parameter read against its
        design may lie beyond them)."""
        if self.kind == 'value':
            return float(value)
        ratio = float(value) / nominal.value(self.param)
        return ratio if self.kind == 'scale' else 1.0 - ratio

    def value(self, nominal: EhaParams, severity: float) -> float:
        if not self.lo <= severity <= self.hi:
            raise TwinError(f'fault {self.name}: severity {severity!r} {self.unit} is out of '
                            f'range; allowed [{self.lo:g}, {self.hi:g}]')
        base = nominal.value(self.param)
        if self.kind == 'scale':
            return base * severity
        if self.kind == 'loss':
            return base * (1.0 - severity)
        return float(severity)


#: name -> fault. Severity 'scale' faults are multipliers (1 = healthy), 'loss' faults fractions
#: lost (0 = healthy), 'value' faults the parameter itself.
FAULTS: dict[str, FaultSpec] = {f.name: f for f in (
    FaultSpec('leakage_growth', 'CLk', 'scale', 1.0, 100.0, 'x CLk',
              'internal port-to-port leakage grows (worn spool lands, piston seal): less '
              'stiffness under load, larger holding error', 10.0),
    FaultSpec('supply_loss', 'PSR_scale', 'loss', 0.0, 0.9, 'fraction of PSR',
              'the valve sees only (1 - severity) of the scheduled supply (pump wear, relief '
              'valve leaking, clogged pressure filter): lower stall force, slower under load',
              0.3),
    FaultSpec('static_friction', 'FSJ', 'scale', 1.0, 50.0, 'x FSJ',
              'break-away friction of the jack seals grows (seal wear, contamination): '
              'stick-slip, dead band around the command', 20.0),
    FaultSpec('dynamic_friction', 'FDJ', 'scale', 1.0, 50.0, 'x FDJ',
              'running friction of the jack seals grows; FSJ is raised with it where it would '
              'fall below FDJ', 15.0),
    FaultSpec('torque_motor_gain_loss', 'GM', 'loss', 0.0, 0.9, 'fraction of GM',
              'torque-motor gain drops (demagnetisation, coil turns shorted): smaller spool '
              'opening per ampere, slower response', 0.7),
    FaultSpec('null_bias', 'CorB', 'value', -5.0e-3, 5.0e-3, 'A',
              'the valve null shifts (spring preload drift, nozzle erosion), a bias current '
              'after the ECU saturation: a steady position error CorB/GAP of the proportional '
              'loop', -5.0e-3),
    FaultSpec('first_stage_flow_loss', 'GQF_AS', 'loss', 0.0, 0.95, 'fraction of GQF/AS',
              'first-stage flow drops (filter or nozzle contamination): the spool moves '
              'slower, the valve bandwidth falls', 0.9),
    FaultSpec('clearance_growth', 'c', 'scale', 1.0, 5.0, 'x c',
              'radial clearance of the spool grows (erosion); HD valve only: softer null, more '
              'null leakage', 3.5),
)}


@dataclasses.dataclass(frozen=True)
class FaultEvent:
    """At simulated time ``at`` [s], set ``param`` to ``value`` (resolved from a fault)."""

    at: float
    param: str
    value: Any
    label: str          # 'leakage_growth=10' or 'CLk=2e-12', for datasets and logs


def resolve(fault: str, severity: float, nominal: EhaParams) -> dict[str, Any]:
    """Parameter values of ``fault`` at ``severity`` relative to ``nominal``."""
    try:
        spec = FAULTS[fault]
    except KeyError:
        raise TwinError(f'unknown fault {fault!r}; expected one of {sorted(FAULTS)}') from None
    values = {spec.param: spec.value(nominal, float(severity))}
    if spec.name == 'dynamic_friction' and values['FDJ'] > nominal.FSJ:
        values['FSJ'] = values['FDJ']
    return values


def combine(nominal: EhaParams, severities: Mapping[str, float]) -> EhaParams:
    """``nominal`` with several faults at once, each severity relative to ``nominal`` (as if
    the others were absent); where two raise FSJ (static friction, and dynamic friction
    lifting it to FDJ), the larger holds."""
    changes: dict[str, Any] = {}
    for fault, severity in severities.items():
        for k, v in resolve(fault, severity, nominal).items():
            changes[k] = max(v, changes[k]) if k == 'FSJ' and k in changes else v
    return nominal.replace(**changes) if changes else nominal


def events_from_raw(raw: Sequence[Mapping[str, Any]] | None, nominal: EhaParams,
                    duration: float) -> list[FaultEvent]:
    """Validate a scenario's ``faults:`` list into events (sorted by time)."""
    events: list[FaultEvent] = []
    for i, item in enumerate(raw or []):
        where = f'scenario.faults[{i}]'
        if not isinstance(item, Mapping):
            raise ScenarioError(f'{where}: expected a mapping with at and fault/severity or '
                                'param/value')
        keys = set(item)
        try:
            at = float(item.get('at', 0.0))
        except (TypeError, ValueError):
            raise ScenarioError(f'{where}.at: expected a time in s, got {item.get("at")!r}'
                                ) from None
        if not 0.0 <= at <= duration:
            raise ScenarioError(f'{where}.at = {at} s lies outside [0, {duration}] s')
        try:
            if keys == {'at', 'fault', 'severity'}:
                values = resolve(str(item['fault']), float(item['severity']), nominal)
                label = f'{item["fault"]}={float(item["severity"]):g}'
            elif keys == {'at', 'param', 'value'}:
                values = {str(item['param']): item['value']}
                nominal.replace(**values)
                label = f'{item["param"]}={item["value"]}'
            else:
                raise ScenarioError(f'{where}: expected keys {{at, fault, severity}} or {{at, '
                                    f'param, value}}, got {sorted(keys)}')
        except (TypeError, ValueError, TwinError) as exc:
            if isinstance(exc, ScenarioError):
                raise
            raise ScenarioError(f'{where}: {exc}') from None
        for param, value in values.items():
            events.append(FaultEvent(at=at, param=param, value=value, label=label))
    return sorted(events, key=lambda e: e.at)


def params_after(events: Sequence[FaultEvent], nominal: EhaParams, t: float) -> EhaParams:
    """The parameters in force at time ``t`` (every event at or before ``t`` applied)."""
    changes = {e.param: e.value for e in events if e.at <= t + 1e-12}
    return nominal.replace(**changes) if changes else nominal


def fault_table() -> list[dict[str, Any]]:
    return [dataclasses.asdict(f) for f in FAULTS.values()]
