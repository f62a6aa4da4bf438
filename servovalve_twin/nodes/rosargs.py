"""The one reader of ``--ros-args -p NAME:=VALUE`` for the executables that are not a single
node (``twin``, ``replay``): it takes the values as ROS parses them (YAML types, params files)
through a short-lived configuration node, and refuses a name it does not know."""

from __future__ import annotations

import sys
from typing import Any, Iterable, Sequence

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from ..errors import TwinError

#: parameters every rclpy node declares by itself
BUILTIN = ('use_sim_time', 'start_type_description_service')


def stray_arguments(argv: Sequence[str]) -> list[str]:
    """Arguments outside ``--ros-args`` (after the program name): these executables take none."""
    return remove_ros_args(list(argv))[1:]


def asks_for_help(argv: Sequence[str]) -> bool:
    """``-h`` or ``--help`` alone outside ``--ros-args``: the usage, exit 0 (it was exit 2, as
    for an argument the executable does not take)."""
    return stray_arguments(argv) in (['-h'], ['--help'])


def init_context(argv: Sequence[str] | None) -> tuple[Context, list[str]]:
    """A private rclpy context initialised with ``argv`` (default ``sys.argv``), without
    rclpy's signal handlers (the caller installs its own)."""
    argv = list(sys.argv if argv is None else argv)
    # parsed first on their own: rcl_init would log its own error line before refusing them
    remove_ros_args(argv)
    context = Context()
    rclpy.init(args=argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
    return context, argv


def ros_parameters(context: Context, name: str, allowed: Iterable[str] = (),
                   allow: Any = None) -> dict[str, Any]:
    """The ``-p`` values given to executable ``name``, by parameter name.

    ``allowed``: the names it accepts; ``allow``: a predicate accepting further names (e.g. the
    physical parameters). Any other name is a :class:`TwinError` listing what is allowed.
    """
    cfg = Node(name, context=context, allow_undeclared_parameters=True,
               automatically_declare_parameters_from_overrides=True)
    try:
        values = {n: p.value for n, p in cfg.get_parameters_by_prefix('').items()}
    finally:
        cfg.destroy_node()
    for builtin in BUILTIN:
        values.pop(builtin, None)
    allowed = tuple(allowed)
    unknown = sorted(n for n in values if n not in allowed and not (allow and allow(n)))
    if unknown:
        raise TwinError(f'{name}: unknown parameter {unknown[0]!r}; expected one of '
                        f'{list(allowed)}' + (' or a physical parameter' if allow else ''))
    return values
