"""A node's physical parameters, declared from the one parameter schema
(:mod:`~..physics.params`) with description, unit and range, and read back, validated."""

from __future__ import annotations

from typing import Any, Callable, Iterable, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..errors import TwinError
from ..physics.params import DEFAULTS, PARAM_FIELDS, EhaParams, param_table

_DERIVED_NOTE = '0.0 = derived'


def declare_physical(node: Node, names: Iterable[str],
                     read_only: Sequence[str] = ('DT',)) -> None:
    """Declare parameters of :class:`EhaParams` with description, unit and range.

    Derived parameters (GM, V0, C4_alpha) are declared as 0.0 meaning "derived".
    """
    rows = {r['name']: r for r in param_table()}
    for name in names:
        r = rows[name]
        desc = ParameterDescriptor(
            name=name, description=f'{r["doc"]} [{r["unit"]}]'
            + (f'; {_DERIVED_NOTE}' if r['derived'] else ''),
            read_only=name in read_only)
        default: Any = r['default']
        if r['kind'] == 'bool':
            desc.type = ParameterType.PARAMETER_BOOL
        elif r['kind'] == 'int':
            desc.type = ParameterType.PARAMETER_INTEGER
            desc.integer_range = [IntegerRange(from_value=int(r['lo']), to_value=int(r['hi']),
                                               step=1)]
        else:
            desc.type = ParameterType.PARAMETER_DOUBLE
            # `-p M:=400` (an integer for a double) is a value, not a type error: the set is
            # checked and coerced by the node's own validation
            desc.dynamic_typing = True
            lo = 0.0 if r['derived'] else float(r['lo'])
            desc.floating_point_range = [FloatingPointRange(from_value=lo,
                                                            to_value=float(r['hi']), step=0.0)]
            default = 0.0 if r['derived'] else float(default)
        node.declare_parameter(name, default, desc)
        value = node.get_parameter(name).value
        if r['kind'] == 'float' and isinstance(value, int) and not isinstance(value, bool):
            # `-p M:=400` given at start-up: stored as the double it means (before any
            # parameter callback exists, so this is not a parameter *set*)
            node.set_parameters([Parameter(name, Parameter.Type.DOUBLE, float(value))])


def integers_as_doubles(params: list[Parameter], doubles) -> list[Parameter]:
    """A pre-set callback's work: an integer given for a double parameter (``ros2 param set
    /plant M 450``) becomes that double, so that it reads back as one."""
    return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in doubles and p.type_ == Parameter.Type.INTEGER else p for p in params]


def physical_from_node(node: Node, names: Iterable[str],
                       base: EhaParams = DEFAULTS) -> EhaParams:
    """``base`` with the node's current values of the parameters ``names`` (validated)."""
    return with_ros_values(base, {name: node.get_parameter(name).value for name in names})


def with_ros_values(base: EhaParams, changes: dict[str, Any]) -> EhaParams:
    """``base`` with ROS parameter values applied (0.0 of a derived parameter = derived)."""
    fixed = {}
    for name, value in changes.items():
        if name not in PARAM_FIELDS:
            continue
        if PARAM_FIELDS[name].default is None and value == 0.0:
            value = None
        fixed[name] = value
    return base.replace(**fixed)


def validation_result(fn: Callable[[], Any]) -> SetParametersResult:
    """Run a validation; a :class:`TwinError` becomes a refusal with its message as reason."""
    try:
        fn()
    except TwinError as exc:
        return SetParametersResult(successful=False, reason=str(exc))
    return SetParametersResult(successful=True)


__all__ = ['declare_physical', 'integers_as_doubles', 'physical_from_node', 'with_ros_values',
           'validation_result']
